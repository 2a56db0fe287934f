"""The composition root: builds a ready loop from the user's choices, wiring every port.

    demo            the built-in demo: a synthetic operator doing the pick-and-place task
    webcam:N        camera index N (or webcam:/dev/videoN)
    video:PATH      a video file, upright (its container's rotation, or --rotate), paced at
                    its frame rate when live from the loop's first tick; --loop-video
                    plays it again at its end
    auto            the first camera that opens, otherwise the demo (with a line saying so)

`realtime=True` (the live app) runs capture and tracking in their own threads and the loop on
the monotonic clock; `realtime=False` (headless runs) reads and tracks each frame in the loop's
thread on a manual clock, as fast as the machine allows, deterministically.

Everything the loop talks to is given to its constructor here: nothing is attached to a
built loop afterwards.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app.compose.options import LoopOptions
from dsteleop.app.inputs.demo import DemoCamera, DemoConfig, DemoOperator, demo_source
from dsteleop.app.inputs.tracked import TrackedHandInput
from dsteleop.app.loop import TeleopLoop
from dsteleop.app.loop.timing import ManualClock, MonotonicClock
from dsteleop.app.plants.kitchen import KitchenTask, simulated_kitchen
from dsteleop.app.ports import Observer, Robot, Task
from dsteleop.app.session.video import FrameRecorder
from dsteleop.app.session.writer import HistoryFile
from dsteleop.errors import ConfigError
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import (
    FrameSource,
    SourceSpec,
    VideoFileSource,
    available_cameras,
    open_source,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Built:
    """A ready loop and what the caller may need beside it.

    Attributes:
        loop: the loop (not running yet; a live source starts with its first tick).
        demo: the built-in demo operator, when the source is the demo.
        source: the resolved source.
        video: the video file behind the hand, when the source is one (its `partial`,
            `end_note()` once it ended).
        rerun: the Rerun logger observing the loop, when asked for (`--rerun`).
    """

    loop: TeleopLoop
    demo: DemoOperator | None
    source: SourceSpec
    video: VideoFileSource | None = None
    rerun: Any = None
    dataset: Any = None

    def close(self) -> None:
        """Close the loop (the recording, the source, the robot), then the live dataset (its
        last episodes written) and the Rerun logger."""
        try:
            self.loop.close()
        finally:
            try:
                if self.dataset is not None:
                    self.dataset.close()
            finally:
                if self.rerun is not None:
                    self.rerun.close()


def hand_mapping(fields: dict[str, Any]) -> MappingConfig | None:
    """The hand's workspace mapping from its fields (`HandInput.mapping_config`, the
    dataclass's own fields); None for a source without one (what a viewer shows)."""
    return MappingConfig(**fields) if fields else None


def resolve_source(spec: SourceSpec) -> SourceSpec:
    """`auto` -> the first camera that opens, or `demo` (with a line saying so)."""
    if spec.kind != "auto":
        return spec
    cams = available_cameras()
    if cams:
        return SourceSpec("webcam", cams[0])
    log.info("no webcam opens: starting the built-in demo (synthetic operator)")
    return SourceSpec("demo")


def build(
    options: LoopOptions,
    *,
    realtime: bool,
    export_scene: bool = False,
    record_root: Path | None = None,
    observers: tuple[Observer, ...] = (),
    mapping: MappingConfig | None = None,
) -> Built:
    """Build the robot and the task, the hand input and the loop (module docstring).

    Args:
        options: the loop options of the command.
        realtime: live threads and clock (True) or headless and deterministic (False).
        export_scene: compute link poses each tick (for a viewer).
        record_root: where a recording requested from the page is written, or None.
        observers: more observers of every tick.
        mapping: camera -> robot mapping (default `MappingConfig()`).
    """
    spec = resolve_source(options.source)
    desc = options.robot.description
    link_config = options.robot.link
    if link_config is not None and abs(link_config.rate_hz * options.loop.dt_s - 1.0) > 1e-6:
        raise ConfigError(
            f"--robot {options.robot}: the link's rate_hz {link_config.rate_hz:g} is not the "
            f"loop's rate {1.0 / options.loop.dt_s:g} Hz (the twin keeps the loop's time)"
        )
    # The hand's fingers drive the robot's: the table comes with the robot's description.
    mapping = dataclasses.replace(
        mapping or MappingConfig(), robot_fingers=tuple((f.name, f.human) for f in desc.fingers)
    )
    # The demo person works in the operator's world (docs/operator.md): the task's goal noise
    # and the link's command delay come from it, unless given on the command line.
    change_to, change_at_s = options.change_mind or (None, DemoConfig.change_at_s)
    demo_config = DemoConfig(seed=options.seed, change_to=change_to, change_at_s=change_at_s)
    goal_noise_m = options.goal_noise_m
    if spec.kind == "demo":
        world = demo_config.world
        if goal_noise_m is None and not options.infer:
            # A told goal's isotropic noise; a robot that infers its goal perceives the
            # candidates through its camera (`robot.perception`: the world's 2 cm along the
            # camera's ray only, 5 mm across it).
            goal_noise_m = world.goal_sigma_m
        if not options.input_delay_given and options.loop.input_delay_s == 0.0:
            options = dataclasses.replace(
                options, loop=dataclasses.replace(options.loop, input_delay_s=world.delay_s)
            )
    task_options: dict[str, Any] = {
        "utensil": options.utensil,
        "infer": options.infer,
        "seed": options.seed,
        "goal_noise_m": goal_noise_m,
        "export_scene": export_scene or options.rerun is not None,
        "time_limit_s": options.time_limit_s,
        "control_dt_s": options.loop.dt_s,  # the world keeps the loop's time
    }
    robot: Robot
    task: Task
    if link_config is None:
        robot, task = simulated_kitchen(desc, **task_options)
    else:
        # The arm at the far end of the link; the task judges it through its twin here
        # (docs/link.md, "Where the task runs").
        from dsteleop.app.link.near import ZenohRobot

        task = KitchenTask(desc, twin=True, **task_options)
        try:
            robot = ZenohRobot(link_config)
        except BaseException:
            task.close()
            raise
        log.info(
            "robot: %s at the far end of %s, judged through its twin",
            desc.name,
            options.robot.link_file,
        )
    rerun: Any = None
    dataset: Any = None
    try:
        task.reset()
        start = robot.reset(0.0).X
        demo: DemoOperator | None = None
        frames: FrameRecorder | None = None
        video: VideoFileSource | None = None
        if spec.kind == "demo":
            if options.record_video:
                log.warning("--record-video: the demo has no camera frames; no video is recorded")
            demo = DemoOperator(
                task.true_goals,
                start,
                demo_config,
                arbitration=options.loop.arbitration,
            )
            source: FrameSource = demo_source(
                demo, DemoCamera(start, mapping), realtime=realtime, seed=options.seed
            )
        else:
            source = open_source(
                spec, realtime=realtime, rotate=options.rotate, loop=options.loop_video
            )
            if isinstance(source, VideoFileSource):
                video = source
            if options.record_video:
                frames = FrameRecorder(source)
                source = frames
        delay = options.loop.input_delay_s
        if realtime:
            # Opened (and the model loaded) now; capture starts with the loop's first tick,
            # so a video plays from its first frame.
            stream = TrackingStream(source, HandTracker()).open()
            hand = TrackedHandInput.from_stream(stream, WorkspaceMapping(mapping), delay)
        else:
            hand = TrackedHandInput.from_source(
                source, HandTracker(), WorkspaceMapping(mapping), delay, t0_s=0.0
            )
        history = None if options.history is None else HistoryFile(options.history)
        meta: dict[str, Any] = {"source_kind": spec.kind, "seed": options.seed}
        if options.rerun is not None:
            from dsteleop.app.rrd.live import RerunLogger

            name = options.record.name if options.record is not None else None
            rerun = RerunLogger(
                options.rerun,
                name or time.strftime("live-%Y%m%d-%H%M%S"),
                scene=task.scene(),
                plant_meta=task.describe(),
            )
            observers = (*observers, rerun)
        if options.record_lerobot is not None:
            from dsteleop.app.lerobot.live import LiveDataset

            dataset = LiveDataset(
                options.record_lerobot, round(options.loop.rate_hz), camera=frames is not None
            )
        loop = TeleopLoop(
            options.loop,
            hand,
            robot,
            task,
            clock=MonotonicClock() if realtime else ManualClock(0.0),
            observers=(*((demo,) if demo is not None else ()), *observers),
            history_file=history,
            frame_recorder=frames,
            record_root=record_root,
            meta=meta,
            episode_sink=None if dataset is None else dataset.put,
        )
    except BaseException:
        robot.close()
        task.close()
        if rerun is not None:
            rerun.close()
        if dataset is not None:
            dataset.close()
        raise
    return Built(loop, demo, spec, video, rerun, dataset)
