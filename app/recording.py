"""Crash-safe session recording and tolerant reading (format: `recordings/README.md`).

A session is a folder:

    meta.json      written atomically (temp file + rename) at start, rewritten at close with
                   the end time and outcome; schema version, dsteleop version, full config
    ticks.jsonl    one JSON object per control tick, appended and flushed as it goes
    video.mp4      optional: the camera frames

A process killed mid-session (even kill -9) leaves `meta.json` from the start and every tick
line that reached the file; the reader skips a truncated last line with a warning and never
raises for it. Floats are written with Python's shortest round-trip repr, so a replay reads
back exactly what the loop used.
"""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from dsteleop import __version__
from dsteleop.errors import DsteleopError

log = logging.getLogger(__name__)

SCHEMA = "dsteleop.session/1"
META = "meta.json"
TICKS = "ticks.jsonl"
VIDEO = "video.mp4"


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to `path` so that readers see the old or the new file, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o644)
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2, sort_keys=True, allow_nan=False, default=_jsonable)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _jsonable(obj: Any) -> Any:
    tolist = getattr(obj, "tolist", None)
    if tolist is not None:
        return tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _clean(value: Any) -> Any:
    """NaN/inf become null (JSON has neither); numpy arrays become lists."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    tolist = getattr(value, "tolist", None)
    if tolist is not None:
        return _clean(tolist())
    return value


class SessionWriter:
    """Writes one session folder; every tick line is flushed to the OS as it is written.

    Args:
        folder: the session folder (created; must not already hold a session).
        meta: metadata (config, mode, goals, mapping, source, ...); schema, version and start
            time are added.
        fsync_every: also fsync the tick file every N ticks (0: only at close). Flushing
            already survives a killed process; fsync guards against a power cut.
    """

    def __init__(self, folder: Path, meta: dict[str, Any], fsync_every: int = 30) -> None:
        self.folder = Path(folder)
        if (self.folder / META).exists():
            raise DsteleopError(f"{self.folder} already holds a session; choose another folder")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.meta = {"schema": SCHEMA, "dsteleop_version": __version__, **_clean(meta)}
            write_json_atomic(self.folder / META, self.meta)
            self._ticks: IO[str] | None = open(self.folder / TICKS, "a", encoding="utf-8")  # noqa: SIM115
        except OSError as exc:
            raise DsteleopError(f"cannot write a session in {self.folder}: {exc.strerror}") from exc
        self._fsync_every = fsync_every
        self.n_ticks = 0

    def write_tick(self, record: dict[str, Any]) -> None:
        """Append one tick record (a JSON object on one line) and flush it."""
        if self._ticks is None:
            raise RuntimeError("session is closed")
        line = json.dumps(_clean(record), separators=(",", ":"), allow_nan=False)
        self._ticks.write(line + "\n")
        self._ticks.flush()
        self.n_ticks += 1
        if self._fsync_every and self.n_ticks % self._fsync_every == 0:
            os.fsync(self._ticks.fileno())

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
            **_clean(extra_meta or {}),
            "n_ticks": self.n_ticks,
            "complete": True,
        }
        write_json_atomic(self.folder / META, self.meta)

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class Session:
    """A session read back: metadata, tick records, and whether the end was truncated."""

    folder: Path
    meta: dict[str, Any]
    ticks: list[dict[str, Any]]
    truncated: bool

    @property
    def name(self) -> str:
        return self.folder.name

    @property
    def complete(self) -> bool:
        return bool(self.meta.get("complete")) and not self.truncated

    @property
    def video(self) -> Path | None:
        p = self.folder / VIDEO
        return p if p.is_file() else None


def is_session(folder: Path) -> bool:
    return (Path(folder) / META).is_file()


def read_session(folder: Path) -> Session:
    """Read a session folder; a truncated last tick line is skipped with a warning.

    Raises:
        DsteleopError: the folder is missing, is not a session, or a line before the last is
            corrupt (one line, naming the file and line).
    """
    folder = Path(folder)
    meta_path = folder / META
    if not folder.is_dir():
        raise DsteleopError(f"session not found: {folder}")
    if not meta_path.is_file():
        raise DsteleopError(f"{folder} is not a dsteleop session (no {META})")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DsteleopError(f"{meta_path}: unreadable metadata ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("schema") != SCHEMA:
        raise DsteleopError(f"{meta_path}: not a {SCHEMA} session (schema {meta.get('schema')!r})")
    ticks, truncated = list(_read_lines(folder / TICKS)), False
    records: list[dict[str, Any]] = []
    for lineno, line, last in ticks:
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict):
                raise ValueError("not an object")
        except ValueError as exc:
            if last:
                log.warning(
                    "%s: skipping a truncated last record (line %d)", folder / TICKS, lineno
                )
                truncated = True
                break
            raise DsteleopError(f"{folder / TICKS}:{lineno}: corrupt record ({exc})") from exc
        records.append(rec)
    return Session(folder, meta, records, truncated)


def _read_lines(path: Path) -> Iterator[tuple[int, str, bool]]:
    """(line number, text, is_last) of the non-empty lines; a missing file has none."""
    if not path.is_file():
        return
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise DsteleopError(f"{path}: unreadable ({exc.strerror})") from exc
    lines = text.split("\n")
    # A file that does not end in a newline was cut mid-record.
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    for k, (lineno, ln) in enumerate(numbered):
        yield lineno, ln, k == len(numbered) - 1
