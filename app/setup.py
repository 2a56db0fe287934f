"""Builds a ready loop from user choices: the hand source, the plant, the demo operator.

Source specs (the `--source` of `dsteleop run` and `dsteleop serve`):

    demo            the built-in demo: a synthetic operator doing the pick-and-place task
    webcam:N        camera index N (or webcam:/dev/videoN)
    video:PATH      a video file (paced at its frame rate when live)
    auto            the first camera that opens, otherwise the demo (with a line saying so)

`realtime=True` (the live app) runs capture and tracking in their own threads and the loop on
the monotonic clock; `realtime=False` (headless runs) reads and tracks each frame in the loop's
thread on a manual clock, as fast as the machine allows, deterministically.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dsteleop.app.demo import DemoCamera, DemoConfig, DemoOperator, demo_source
from dsteleop.app.hand_input import TrackedHandInput
from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.plant import KitchenPlant
from dsteleop.app.timing import ManualClock, MonotonicClock
from dsteleop.app.video_tee import VideoTee
from dsteleop.arbitration import OperatorHistory
from dsteleop.errors import DsteleopError
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import FrameSource, VideoFileSource, WebcamSource, available_cameras

log = logging.getLogger(__name__)

HISTORY_FILE = "operator_history.json"


@dataclass(frozen=True)
class Setup:
    """What to build.

    Attributes:
        source: source spec (module docstring).
        loop: loop settings (mode, rates, stale policy, arbitration hyper-parameters).
        utensil: utensil to pick.
        seed: seed of the goal noise and of the demo operator.
        goal_noise_m: goal position noise [m] (None: the task's default).
        realtime: live threads and clock (True) or headless and deterministic (False).
        mapping: camera -> robot mapping.
        export_scene: compute link poses each tick (for a viewer).
        history_dir: where the operator history persists (the recording root), or None.
        record_video: also record the camera frames of a session (webcam and video sources),
            for `dsteleop replay --retrack`.
    """

    source: str = "demo"
    loop: LoopConfig = field(default_factory=LoopConfig)
    utensil: str = "spoon"
    seed: int = 0
    goal_noise_m: float | None = None
    realtime: bool = True
    mapping: MappingConfig = field(default_factory=MappingConfig)
    export_scene: bool = False
    history_dir: Path | None = None
    record_video: bool = False


@dataclass
class Built:
    """A ready loop and what the caller may need beside it."""

    loop: TeleopLoop
    demo: DemoOperator | None
    source_kind: str


def _camera_source(spec: str) -> FrameSource:
    dev: int | str = int(spec) if spec.isdigit() else spec
    return WebcamSource(dev)


def resolve_source(spec: str) -> str:
    """`auto` -> `webcam:<first camera that opens>` or `demo`."""
    if spec != "auto":
        return spec
    cams = available_cameras()
    if cams:
        return f"webcam:{cams[0]}"
    log.info("no webcam opens: starting the built-in demo (synthetic operator)")
    return "demo"


def load_history(folder: Path | None) -> OperatorHistory:
    if folder is None:
        return OperatorHistory()
    path = Path(folder) / HISTORY_FILE
    if not path.is_file():
        return OperatorHistory()
    import json

    try:
        return OperatorHistory.from_dict(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError) as exc:
        raise DsteleopError(f"{path}: unreadable operator history ({exc})") from exc


def save_history(folder: Path, history: OperatorHistory) -> None:
    from dsteleop.app.recording import write_json_atomic

    write_json_atomic(Path(folder) / HISTORY_FILE, history.to_dict())


def build(setup: Setup) -> Built:
    """Build the plant, the hand input and the loop (module docstring)."""
    spec = resolve_source(setup.source)
    plant = KitchenPlant(
        setup.utensil, setup.seed, setup.goal_noise_m, export_scene=setup.export_scene
    )
    try:
        start = plant.reset()
        clock = MonotonicClock() if setup.realtime else ManualClock(0.0)
        mapping = WorkspaceMapping(setup.mapping)
        demo: DemoOperator | None = None
        if spec == "demo":
            demo = DemoOperator(plant.true_goals, start, DemoConfig(seed=setup.seed))
            source: FrameSource = demo_source(
                demo, DemoCamera(start, setup.mapping), realtime=setup.realtime, seed=setup.seed
            )
            kind = "demo"
        elif spec.startswith("webcam:"):
            source = _camera_source(spec.split(":", 1)[1])
            kind = "webcam"
        elif spec.startswith("video:"):
            path = Path(spec.split(":", 1)[1])
            if not path.is_file():
                raise DsteleopError(f"video not found: {path}")
            source = VideoFileSource(path, realtime=setup.realtime)
            kind = "video"
        else:
            raise DsteleopError(f"unknown source {spec!r} (use demo, webcam:N, video:PATH or auto)")
        tee: VideoTee | None = None
        if setup.record_video and kind in ("webcam", "video"):
            tee = VideoTee(source)
            source = tee
        delay = setup.loop.input_delay_s
        if setup.realtime:
            stream = TrackingStream(source, HandTracker()).start()
            hand = TrackedHandInput.from_stream(stream, mapping, delay)
        else:
            hand = TrackedHandInput.from_source(source, HandTracker(), mapping, delay, t0_s=0.0)
        meta: dict[str, Any] = {"source_kind": kind, "seed": setup.seed}
        loop = TeleopLoop(
            setup.loop, hand, plant, clock=clock, history=load_history(setup.history_dir), meta=meta
        )
    except BaseException:
        plant.close()
        raise
    if demo is not None:
        demo_op = demo
        loop.on_task_reset = demo_op.restart
        sub = loop.broadcaster.subscribe() if setup.realtime else None
        if sub is not None:
            import threading

            def watch() -> None:
                while True:
                    snap = sub.wait(1.0)
                    if snap is not None:
                        demo_op.watch(snap)

            threading.Thread(target=watch, name="dsteleop-demo-eyes", daemon=True).start()
    if setup.history_dir is not None:
        folder = setup.history_dir
        loop.on_segment_end = lambda h: save_history(folder, h)
        loop.record_root = folder
    if tee is not None:
        video_tee = tee
        loop.on_recording = lambda f: video_tee.start(f) if f is not None else video_tee.stop()
    return Built(loop, demo, kind)
