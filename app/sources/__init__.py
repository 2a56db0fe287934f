"""Sources: what drives the operator's hand in `run` and `serve` (`--source`), each a plug-in.

    demo            the built-in demo: a simulated person doing the task (app/inputs/demo.py)
    auto            the first camera that opens, otherwise the demo (with a line saying so)
    webcam:N        camera index N (or webcam:/dev/videoN, or N)
    video:PATH      a video file (or a bare path to one), upright, paced at its rate live
    images:DIR      a folder of still images (or a bare path to one)
    synthetic       the scripted synthetic hand of the tracking tests

A source is one module here that defines `KIND` (or `KINDS`), a `SourceKind`: its word in
the `--source` grammar, whether it takes a target, whether its frames have pixels and
whether it only runs live, and how it is opened for a loop (`open`, with a `SourceContext`):
into camera frames for the tracking pipeline (`Opened.frames`: a camera, a video, the demo's
rendered hand) or into a `ports.HandInput` of its own (`Opened.hand`: an input that is not a
camera: a recorded hand, a glove, a 3-D mouse). `BUILTIN` lists the modules, one line each;
`register` adds one from elsewhere (a test, a plug-in). The camera kinds are the tracking
package's (`tracking.sources`, whose grammar knows nothing of the demo or of `auto`).
Adding one: docs/ARCHITECTURE.md, "Adding a source".
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dsteleop.errors import ConfigError
from dsteleop.tracking import sources as tracking_sources
from dsteleop.tracking.sources import SourceSpec

if TYPE_CHECKING:
    from dsteleop.app.ports import HandInput, Observer, Task
    from dsteleop.arbitration import ArbitrationConfig, HandState
    from dsteleop.tracking.mapping import MappingConfig
    from dsteleop.tracking.sources import FrameSource, VideoFileSource

#: The built-in sources' modules, each defining KIND or KINDS (in the grammar's order).
BUILTIN = (
    "dsteleop.app.sources.demo",
    "dsteleop.app.sources.auto",
    "dsteleop.app.sources.camera",
)


@dataclass(frozen=True)
class SourceContext:
    """What a source may need when it is opened for a loop.

    Attributes:
        task: the loop's task (its true goals, for a simulated person).
        X_start: the robot's palm at home, where the task starts.
        mapping: the camera -> robot mapping (with the robot's fingers).
        arbitration: the loop's arbitration configuration.
        realtime: live (threads, the monotonic clock) or headless (deterministic).
        seed: the run's seed.
        input_delay_s: the injected input delay [s] (a hand input of its own applies it).
        rotate: turn camera or video frames [deg clockwise], or None.
        loop_video: play a video again at its end.
        change_mind: the demo person turns to this utensil this many seconds into each
            trial (`--change-mind`), or None.
    """

    task: Task
    X_start: HandState
    mapping: MappingConfig
    arbitration: ArbitrationConfig
    realtime: bool
    seed: int
    input_delay_s: float
    rotate: int | None = None
    loop_video: bool = False
    change_mind: tuple[str, float] | None = None


@dataclass(frozen=True)
class Opened:
    """A source opened for a loop: camera frames for the tracking pipeline, or a hand input
    of its own (exactly one).

    Attributes:
        frames: frames to track (the outputs may wrap them: the video records them).
        hand: a hand input that needs no tracking.
        observers: observers of every tick it needs (the demo person's eyes).
        video: the video file behind the frames, when it is one (its end, partial or not).
    """

    frames: FrameSource | None = None
    hand: HandInput | None = None
    observers: tuple[Observer, ...] = ()
    video: VideoFileSource | None = None

    def __post_init__(self) -> None:
        if (self.frames is None) == (self.hand is None):
            raise ConfigError("a source opens into frames or a hand input, exactly one")


@dataclass(frozen=True)
class Defaults:
    """What a source's world sets unless the command line does (the demo's operator world:
    its goal noise and its link's delay, docs/operator.md); None: the loop's own."""

    goal_noise_m: float | None = None
    input_delay_s: float | None = None


@dataclass(frozen=True)
class SourceKind:
    """A source's plug-in (module docstring).

    Attributes:
        name: its word in `--source` (`name` or `name:TARGET`).
        grammar: how the grammar writes it (e.g. "video:PATH (or a video file)").
        open: opens it for a loop (the parsed spec, the context).
        target: it takes a target (`name:TARGET`); False: the bare word only.
        pixels: its frames are camera pixels (`--record-video` can record them).
        live: it runs in real time only (a camera: `run` goes real time).
        label: the page's words for it (default: the spec as written).
        resolve: another source it stands for (`auto`: a camera, else the demo), or None.
        defaults: what its world sets unless the command line does, for a seed.
        info: what the page shows about it (the demo's world), or None.
        tracked: `dsteleop track` reads it (a tracking source).
    """

    name: str
    grammar: str
    open: Callable[[SourceSpec, SourceContext], Opened]
    target: bool = False
    pixels: bool = False
    live: bool = False
    label: Callable[[SourceSpec], str] = str
    resolve: Callable[[SourceSpec], SourceSpec] | None = None
    defaults: Callable[[int], Defaults] = field(default=lambda seed: Defaults())
    info: Callable[[], dict[str, Any] | None] = field(default=lambda: None)
    tracked: bool = False


_BUILTIN: list[SourceKind] = []
_EXTRA: list[SourceKind] = []


def registered() -> tuple[SourceKind, ...]:
    """Every source, the built-in ones first (`BUILTIN`'s order), then those registered."""
    if not _BUILTIN:
        for m in BUILTIN:
            module = importlib.import_module(m)
            _BUILTIN.extend(getattr(module, "KINDS", None) or (module.KIND,))
    return (*_BUILTIN, *_EXTRA)


def kind(name: str) -> SourceKind:
    """The registered source `name`.

    Raises:
        ConfigError: no source has that name.
    """
    for k in registered():
        if k.name == name:
            return k
    raise ConfigError(f"unknown source kind {name!r} ({grammar()})")


def register(new: SourceKind) -> SourceKind:
    """Add a source (its name must be new)."""
    if any(k.name == new.name for k in registered()):
        raise ConfigError(f"source {new.name!r}: a source of that name is registered already")
    _EXTRA.append(new)
    return new


def unregister(old: SourceKind) -> None:
    """Remove a source `register` added."""
    _EXTRA.remove(old)


def grammar() -> str:
    """The `--source` grammar: every registered source, as its module writes it."""
    words = [k.grammar for k in registered()]
    return ", ".join(words[:-1]) + f", or {words[-1]}" if len(words) > 1 else words[0]


def parse(text: str) -> SourceSpec:
    """A `--source` value: a registered source's word (with its target, if it takes one),
    else the tracking grammar's forms (a bare path or camera index told by its type).

    Raises:
        ConfigError: an unknown kind, a kind without its target, a target where it takes none.
    """
    text = str(text).strip()
    if not text:
        raise ConfigError(f"--source is empty ({grammar()})")
    word, sep, target = text.partition(":")
    own = next((k for k in registered() if k.name == word), None)
    if own is not None:
        if own.target and not target:
            raise ConfigError(f"--source {word}: needs a target, e.g. {word}:... ({grammar()})")
        if not own.target and sep:
            raise ConfigError(f"--source {word} takes no target, got {text!r}")
        return SourceSpec(own.name, target)
    spec = tracking_sources.parse_source(text, grammar())
    kind(spec.kind)  # a tracking kind no module registered is unknown here
    return spec
