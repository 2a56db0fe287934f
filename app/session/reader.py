"""Reading sessions back: metadata and tick records, tolerant of a crash-truncated end."""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app.jsonable import read_json
from dsteleop.app.session.episodes import Episode, episode_records, split
from dsteleop.app.session.schema import READABLE, SCHEMA, TickRecord, decode
from dsteleop.app.session.video import FRAMES, VIDEO
from dsteleop.app.session.writer import META, TICKS
from dsteleop.arbitration import Mode, OperatorHistory
from dsteleop.errors import FormatError, InputError
from dsteleop.robot.description import DEFAULT_ROBOT

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Session:
    """A session read back.

    Attributes:
        folder: where it is.
        meta: its metadata (`recordings/README.md`).
        records: every complete tick, in order (of the episode, in a view of one).
        truncated: the last line was cut short (a killed process) and was skipped.
        episode: the episode this is a view of (`of_episode`), or None for the whole.
    """

    folder: Path
    meta: dict[str, Any]
    records: tuple[TickRecord, ...]
    truncated: bool
    episode: Episode | None = None

    @property
    def name(self) -> str:
        """The folder's name; with `/epN` for a view of episode N."""
        base = self.folder.name
        return base if self.episode is None else f"{base}/ep{self.episode.index}"

    @functools.cached_property
    def episodes(self) -> tuple[Episode, ...]:
        """Its episodes, split from the ticks (`session.episodes`) as the recorder split
        them; the utensil of each from the metadata when it says. One still open at the end
        is "stopped" in a closed session and "incomplete" in a killed one."""
        if self.episode is not None:
            return (self.episode,)
        found = split(self.records, "stopped" if self.meta.get("complete") else "incomplete")
        utensils = {
            int(e.get("index", -1)): str(e.get("utensil", ""))
            for e in self.meta.get("episodes", ())
            if isinstance(e, dict)
        }
        default = str(self.meta.get("plant", {}).get("utensil", ""))
        return tuple(
            dataclasses.replace(e, utensil=e.utensil or utensils.get(e.index) or default)
            for e in found
        )

    def of_episode(self, episode: Episode) -> Session:
        """A view of one episode: its ticks, and the plant metadata with its utensil, so
        every replay of a session replays the episode."""
        plant = dict(self.meta.get("plant", {}))
        if episode.utensil:
            plant["utensil"] = episode.utensil
        return dataclasses.replace(
            self,
            meta={**self.meta, "plant": plant},
            records=tuple(episode_records(self.records, episode)),
            episode=episode,
        )

    @property
    def complete(self) -> bool:
        return bool(self.meta.get("complete")) and not self.truncated

    @property
    def dims(self) -> tuple[str, ...]:
        return tuple(self.meta.get("dims", ()))

    @property
    def robot_name(self) -> str:
        """The recorded robot's description name ("iiwa", "panda", ...); the iiwa for a
        session recorded before robots were descriptions."""
        robot = self.meta.get("robot")
        name = robot.get("name") if isinstance(robot, dict) else None
        return str(name or DEFAULT_ROBOT)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The robot's joints of the ticks' `joints` (schema 4); () when it recorded none."""
        return tuple(str(n) for n in self.meta.get("joint_names") or ())

    @property
    def joint_units(self) -> tuple[str, ...]:
        """Each joint's unit ("rad" or "m"), in `joint_names` order."""
        return tuple(str(u) for u in self.meta.get("joint_units") or ())

    @property
    def mode(self) -> Mode:
        return Mode.parse(str(self.meta.get("mode", "DS")))

    @property
    def history(self) -> OperatorHistory | None:
        h = self.meta.get("operator_history")
        return None if h is None else OperatorHistory.from_dict(h)

    @property
    def video(self) -> Path | None:
        p = self.folder / VIDEO
        return p if p.is_file() else None

    @property
    def frames(self) -> Path | None:
        p = self.folder / FRAMES
        return p if p.is_file() else None


def looks_like_session(folder: Path) -> bool:
    """A session folder, or what is left of one without its metadata."""
    return any((Path(folder) / n).is_file() for n in (META, TICKS, FRAMES))


def sessions_in(path: Path) -> list[Path]:
    """The sessions a command-line path names: the folder itself when it looks like a
    session, else the sub-folders that do, sorted (none for a file). A folder with what a
    session holds but no meta.json counts, so that `read_session` refuses it in one line:
    no command skips it silently."""
    path = Path(path)
    if looks_like_session(path):
        return [path]
    if not path.is_dir():
        return []
    return sorted(q for q in path.iterdir() if q.is_dir() and looks_like_session(q))


def read_session(folder: Path, warn_truncated: bool = True) -> Session:
    """Read a session folder; a truncated last tick line is skipped with a warning
    (`warn_truncated=False`: silently, for a session read again after a first read warned;
    `Session.truncated` says it either way).

    Raises:
        InputError: the folder is missing, is not a session (no metadata), is of an unknown
            schema, holds no tick, or a line before the last is corrupt (one line, naming the
            file and line).
    """
    folder = Path(folder)
    meta_path = folder / META
    if not folder.is_dir():
        raise InputError(f"session not found: {folder}")
    if not meta_path.is_file():
        if any((folder / name).is_file() for name in (TICKS, FRAMES, VIDEO)):
            raise InputError(
                f"{folder}: a session folder without its {META} (its metadata is lost), "
                "which cannot be replayed"
            )
        raise InputError(f"{folder} is not a dsteleop session (no {META})")
    meta = read_json(meta_path, "session metadata")
    if not isinstance(meta, dict) or meta.get("schema") not in READABLE:
        schema = meta.get("schema") if isinstance(meta, dict) else None
        raise InputError(
            f"{meta_path}: a session of schema {schema!r}, which this version cannot read "
            f"(it reads {', '.join(READABLE)}; {SCHEMA} is the current one)"
        )
    dims = tuple(str(d) for d in meta.get("dims", ()))
    records: list[TickRecord] = []
    truncated = False
    for lineno, line, last in _read_lines(folder / TICKS):
        try:
            raw = json.loads(line)
            if not isinstance(raw, dict):
                raise FormatError("not an object")
        except ValueError as exc:
            if last:
                if warn_truncated:
                    log.warning(
                        "%s: skipping a truncated last record (line %d)", folder / TICKS, lineno
                    )
                truncated = True
                break
            raise InputError(f"{folder / TICKS}:{lineno}: corrupt record ({exc})") from exc
        try:
            records.append(decode(raw, dims))
        except InputError as exc:
            raise InputError(f"{folder / TICKS}:{lineno}: {exc}") from None
    if not records:
        raise InputError(f"{folder}: an empty session (no tick in {TICKS}): nothing to replay")
    return Session(folder, meta, tuple(records), truncated)


def _read_lines(path: Path) -> Iterator[tuple[int, str, bool]]:
    """(line number, text, is_last) of the non-empty lines; a missing file has none."""
    if not path.is_file():
        return
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{path}: unreadable ({exc.strerror})") from exc
    numbered = [(i + 1, ln) for i, ln in enumerate(text.split("\n")) if ln.strip()]
    for k, (lineno, ln) in enumerate(numbered):
        yield lineno, ln, k == len(numbered) - 1
