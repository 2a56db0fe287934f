"""Outputs: what a run writes beside the session the loop records, each a plug-in.

    video     --record-video        the camera's frames beside each session (video.mp4)
    lerobot   --record-lerobot DIR  each recorded episode into a LeRobot v3.0 dataset
    rerun     --rerun FILE.rrd, --rerun-connect [ADDR]   a Rerun recording, live

An output is one module here that defines `KIND`, an `OutputKind`: its name (the key of
`LoopOptions.outputs` and of the command's summary), its options on `run` and `serve`, how
they are read and checked (before anything opens; a bad value is one line and exit 2), and
how it is opened for a loop; the `ports.Output` it opens gets the loop's hooks (every tick,
each session's start and stop, each recorded episode, the hand's frames, close, summary;
`OutputBase` does nothing in each, so it writes only those it needs). `BUILTIN` lists the
modules, one line each; `register` adds one from elsewhere (a test, a plug-in). Adding one:
docs/ARCHITECTURE.md, "Adding an output".

The session itself (ticks.jsonl, episodes, meta.json; `--record DIR`) is the loop's own
output, the one the others hang on: `session.recording.Recording` opens and closes it and
tells every output.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from dsteleop.errors import ConfigError

if TYPE_CHECKING:
    from dsteleop.app.ports import Output, Task
    from dsteleop.app.session.episodes import Episode
    from dsteleop.app.session.schema import TickRecord
    from dsteleop.tracking.sources import FrameSource, SourceSpec

#: The built-in outputs' modules, each defining KIND, in the order they are opened, told
#: and closed (the video before a dataset that reads it).
BUILTIN = (
    "dsteleop.app.outputs.video",
    "dsteleop.app.outputs.lerobot",
    "dsteleop.app.outputs.rerun",
)

#: The output that records the camera's frames (opened, with the setting True, for any
#: output that `wants_frames` when the source has them).
FRAMES = "video"


class OutputBase:
    """A `ports.Output` that does nothing in any hook: an output overrides what it needs."""

    def wrap_source(self, source: FrameSource) -> FrameSource:
        return source

    def observe(self, record: TickRecord) -> None:
        return None

    def start_session(self, folder: Path) -> None:
        return None

    def stop_session(self) -> None:
        return None

    def episode(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        return None

    def summary(self) -> dict[str, Any] | None:
        return None

    def close(self) -> None:
        return None


@dataclass(frozen=True)
class OutputContext:
    """What an output may need when it is opened for a loop.

    Attributes:
        task: the loop's task (its scene and description).
        rate_hz: the loop's rate [Hz].
        record: the session folder (run) or root (serve) of `--record`, or None.
        pixels: the hand's source has camera frames (not the demo's synthetic hand).
        frames: the camera's frames are recorded beside each session (the `FRAMES` output).
    """

    task: Task
    rate_hz: float
    record: Path | None
    pixels: bool
    frames: bool


#: An output's checked setting (rerun: its `RerunTarget`, lerobot: its root folder).
T = TypeVar("T")


@dataclass(frozen=True)
class OutputKind(Generic[T]):
    """An output's plug-in (module docstring), generic over its setting T, so that its
    parse, open and sessions are checked against each other (the registry holds
    `OutputKind[Any]`).

    Attributes:
        name: its key in `LoopOptions.outputs` and in the command's summary.
        add_arguments: adds its options to `run`'s and `serve`'s parser.
        parse: its checked setting from the parsed arguments and the source; None when it
            was not asked for. Raises the project's errors (one line, exit 2).
        open: opens it for a loop (its setting, the context); None: nothing to write for
            this loop (after a line saying why).
        wants_frames: it reads the camera's frames recorded beside the session (`FRAMES`
            is then opened too, when the source has them).
        wants_scene: it needs the scene's poses each tick (the task exports them).
        sessions: where the sessions behind it are recorded when `--record` is not given
            (it needs sessions: one is recorded from the start), or None.
    """

    name: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    parse: Callable[[argparse.Namespace, SourceSpec], T | None]
    open: Callable[[T, OutputContext], Output | None]
    wants_frames: bool = False
    wants_scene: bool = False
    sessions: Callable[[T], Path] | None = None


_EXTRA: list[OutputKind[Any]] = []
_BUILTIN: list[OutputKind[Any]] = []


def registered() -> tuple[OutputKind[Any], ...]:
    """Every output, the built-in ones first (in `BUILTIN`'s order), then those registered."""
    if not _BUILTIN:
        _BUILTIN.extend(importlib.import_module(m).KIND for m in BUILTIN)
    return (*_BUILTIN, *_EXTRA)


def kind(name: str) -> OutputKind[Any]:
    """The registered output `name`.

    Raises:
        ConfigError: no output has that name.
    """
    for k in registered():
        if k.name == name:
            return k
    names = ", ".join(k.name for k in registered())
    raise ConfigError(f"unknown output {name!r} (outputs: {names})")


def register(new: OutputKind[T]) -> OutputKind[T]:
    """Add an output (its name must be new)."""
    if any(k.name == new.name for k in registered()):
        raise ConfigError(f"output {new.name!r}: an output of that name is registered already")
    _EXTRA.append(new)
    return new


def unregister(old: OutputKind[Any]) -> None:
    """Remove an output `register` added."""
    _EXTRA.remove(old)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Every output's options (`run`, `serve`)."""
    for k in registered():
        k.add_arguments(parser)


def parse(args: argparse.Namespace, source: SourceSpec, pixels: bool) -> dict[str, Any]:
    """The outputs asked for, with their checked settings, in the registry's order; the
    frames' output added for an output that wants the camera's frames when the source has
    them (`pixels`)."""
    settings = {k.name: k.parse(args, source) for k in registered()}
    if pixels and any(k.wants_frames and settings[k.name] is not None for k in registered()):
        settings[FRAMES] = settings[FRAMES] or True
    return {name: s for name, s in settings.items() if s is not None}


def session_root(settings: Mapping[str, Any]) -> Path | None:
    """Where sessions are recorded for the outputs asked for when `--record` is not given:
    the first that needs sessions (`OutputKind.sessions`), or None."""
    for k in registered():
        if k.name in settings and k.sessions is not None:
            return k.sessions(settings[k.name])
    return None
