"""Crash-safe session recording (the format: `recordings/README.md`).

A session is a folder:

    meta.json      written atomically (temp file + rename) at start, rewritten as each episode
                   ends (its outcome, duration, events) and at close; schema version,
                   dsteleop version, full config
    ticks.jsonl    one JSON object per control tick (`schema.encode`), appended and flushed
    video.mp4      optional: the camera frames (`video.FrameRecorder`)

A process killed mid-session (even kill -9) leaves `meta.json` from the start and every tick
line that reached the file; the reader skips a truncated last line with a warning. The
`Recorder` writes on its own thread, so a slow disk never stalls the loop, and loses nothing:
its queue holds every record until it is written.

The operator's previous attempts (eq 6, last term) persist only where the user asks
(`--history FILE`, `HistoryFile`): without it a run starts from an empty history and keeps
none, so that it is a function of its inputs and seed. The history a session started from is
in its `meta.json` (`operator_history`, and `operator_history_file`: the file's path and the
SHA-256 of its content when it was read).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import logging
import os
import queue
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from dsteleop import __version__
from dsteleop.app.jsonable import jsonable
from dsteleop.app.session.episodes import Episode
from dsteleop.app.session.schema import SCHEMA, TickRecord, encode
from dsteleop.arbitration import OperatorHistory
from dsteleop.errors import InputError

log = logging.getLogger(__name__)

META = "meta.json"
TICKS = "ticks.jsonl"
#: The usual name of an operator history file (`--history FILE` may name any file).
HISTORY_FILE = "operator_history.json"


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to `path` so that readers see the old or the new file, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o644)
        with os.fdopen(fd, "w") as f:
            json.dump(jsonable(data), f, indent=2, sort_keys=True, allow_nan=False)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def new_session_folder(root: Path, mode: str, utensil: str) -> Path:
    """A new folder under `root` named `<date>-<time>-<mode>-<utensil>` (unique)."""
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    folder = root / f"{stamp}-{mode}-{utensil}"
    k = 1
    while folder.exists():
        k += 1
        folder = root / f"{stamp}-{mode}-{utensil}-{k}"
    return folder


class SessionWriter:
    """Writes one session folder; every tick line is flushed to the OS as it is written.

    Args:
        folder: the session folder (created; must not already hold a session).
        meta: metadata (config, mode, goals, mapping, source, ...); schema, version and start
            time are added.
        fsync_every: also fsync the tick file every N ticks (0: only at close). Flushing
            already survives a killed process; fsync guards against a power cut.

    Raises:
        InputError: the folder holds a session already, or cannot be written.
    """

    def __init__(self, folder: Path, meta: dict[str, Any], fsync_every: int = 30) -> None:
        self.folder = Path(folder)
        if (self.folder / META).exists():
            raise InputError(f"{self.folder} already holds a session; choose another folder")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.meta = {"schema": SCHEMA, "dsteleop_version": __version__, **jsonable(meta)}
            write_json_atomic(self.folder / META, self.meta)
            self._ticks: IO[str] | None = open(self.folder / TICKS, "a", encoding="utf-8")  # noqa: SIM115
        except OSError as exc:
            raise InputError(f"cannot write a session in {self.folder}: {exc.strerror}") from exc
        self._fsync_every = fsync_every
        self.n_ticks = 0

    def write_tick(self, record: dict[str, Any]) -> None:
        """Append one tick record (a JSON object on one line) and flush it."""
        if self._ticks is None:
            raise RuntimeError("session is closed")
        line = json.dumps(jsonable(record), separators=(",", ":"), allow_nan=False)
        self._ticks.write(line + "\n")
        self._ticks.flush()
        self.n_ticks += 1
        if self._fsync_every and self.n_ticks % self._fsync_every == 0:
            os.fsync(self._ticks.fileno())

    def add_episode(self, episode: dict[str, Any]) -> None:
        """An episode ended: fsync the ticks so far, then rewrite meta.json with it added to
        `episodes` (`episodes.Episode.to_dict`)."""
        if self._ticks is not None:
            self._ticks.flush()
            os.fsync(self._ticks.fileno())
        episodes = [*self.meta.get("episodes", []), jsonable(episode)]
        self.meta = {**self.meta, "episodes": episodes}
        write_json_atomic(self.folder / META, self.meta)

    def close(self, extra_meta: dict[str, Any] | None = None) -> None:
        """Flush, fsync and close the tick log; rewrite meta.json with `extra_meta` added."""
        if self._ticks is None:
            return
        self._ticks.flush()
        os.fsync(self._ticks.fileno())
        self._ticks.close()
        self._ticks = None
        self.meta = {
            **self.meta,
            **jsonable(extra_meta or {}),
            "n_ticks": self.n_ticks,
            "complete": True,
        }
        write_json_atomic(self.folder / META, self.meta)

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: Gets each episode once its ticks are written: the session's folder and metadata, the
#: episode, and its tick records (e.g. `lerobot.live.LiveDataset.put`). Called on the
#: recorder's thread.
EpisodeSink = Callable[[Path, dict[str, Any], Episode, tuple[TickRecord, ...]], None]


class Recorder:
    """Encodes and writes tick records, and the episodes as they end, on its own thread
    (module docstring), in the order they were put.

    Args:
        writer: the session's writer.
        on_episode: also hands each ended episode, with its ticks, to this sink.

    Attributes:
        lines: records put so far (the line number the next one gets).
        episodes: episodes put so far.
    """

    def __init__(self, writer: SessionWriter, on_episode: EpisodeSink | None = None) -> None:
        self.writer = writer
        self._on_episode = on_episode
        self._pending: list[TickRecord] = []  # the ticks since the last episode ended
        self._first = 0  # the line number of _pending[0]
        self._q: queue.SimpleQueue[TickRecord | Episode | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="dsteleop-recorder", daemon=True)
        self._thread.start()
        self.lines = 0
        self.episodes = 0

    @property
    def folder(self) -> Path:
        return self.writer.folder

    def put(self, record: TickRecord) -> None:
        self._q.put(record)
        self.lines += 1

    def end_episode(self, episode: Episode) -> None:
        """Record an episode that ended (after the ticks already put)."""
        self._q.put(episode)
        self.episodes += 1

    def _run(self) -> None:
        while (item := self._q.get()) is not None:
            if isinstance(item, Episode):
                self.writer.add_episode(item.to_dict())
                if self._on_episode is not None:
                    lo, hi = item.first - self._first, item.last + 1 - self._first
                    ticks = tuple(self._pending[max(lo, 0) : hi])
                    self._pending = self._pending[hi:]
                    self._first = item.last + 1
                    self._on_episode(self.writer.folder, self.writer.meta, item, ticks)
            else:
                self.writer.write_tick(encode(item))
                if self._on_episode is not None:
                    self._pending.append(item)

    def close(self, extra_meta: dict[str, Any]) -> None:
        """Write what is queued, then close the session with `extra_meta`."""
        self._q.put(None)
        self._thread.join()
        self.writer.close(extra_meta)


class HistoryFile:
    """An operator history kept in one JSON file (`--history FILE`).

    Args:
        path: the file (created at the first save when it does not exist).

    Attributes:
        sha256: hex SHA-256 of the file's content as last loaded or saved (None before
            either, or when there was no file).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.sha256: str | None = None

    def load(self) -> OperatorHistory:
        """The saved history (empty when there is none).

        Raises:
            InputError: the file exists but cannot be read, or is not an operator history.
        """
        if not self.path.exists():
            self.sha256 = None
            return OperatorHistory()
        try:
            data = self.path.read_bytes()
            history = OperatorHistory.from_dict(json.loads(data))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise InputError(f"{self.path}: unreadable operator history ({exc})") from None
        self.sha256 = hashlib.sha256(data).hexdigest()
        return history

    def describe(self) -> dict[str, Any]:
        """What a session's metadata says about it: the path and the content's hash."""
        return {"path": str(self.path.resolve()), "sha256": self.sha256}

    def save(self, history: OperatorHistory) -> None:
        """Replace the file with `history` (atomically).

        Raises:
            InputError: it cannot be written (the command checked it could at start-up,
                `outpaths`; this is a disk that filled up or a folder changed since).
        """
        try:
            write_json_atomic(self.path, history.to_dict())
            self.sha256 = hashlib.sha256(self.path.read_bytes()).hexdigest()
        except OSError as exc:
            raise InputError(
                f"--history {self.path}: cannot write the operator history ({exc.strerror or exc})"
            ) from None
