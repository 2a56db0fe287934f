"""The composition root: builds a ready loop from the user's choices, wiring every port.

The hand comes from the source's plug-in (`app.sources`: the demo, a camera, a video, ...):
camera frames through the tracking pipeline, or a hand input of its own; what is written
comes from the outputs' plug-ins (`app.outputs`).

`realtime=True` (the live app) runs capture and tracking in their own threads and the loop on
the monotonic clock; `realtime=False` (headless runs) reads and tracks each frame in the loop's
thread on a manual clock, as fast as the machine allows, deterministically.

Everything the loop talks to is given to its constructor here: nothing is attached to a
built loop afterwards.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app import outputs as output_registry
from dsteleop.app import sources
from dsteleop.app.compose.options import LoopOptions
from dsteleop.app.inputs.tracked import TrackedHandInput
from dsteleop.app.loop import TeleopLoop
from dsteleop.app.loop.timing import ManualClock, MonotonicClock
from dsteleop.app.outputs import OutputContext
from dsteleop.app.plants.kitchen import KitchenTask, simulated_kitchen
from dsteleop.app.ports import HandInput, Observer, Output, Robot, Task
from dsteleop.app.session.writer import HistoryFile
from dsteleop.app.sources import SourceContext
from dsteleop.arbitration.se3 import so3_exp, so3_log
from dsteleop.errors import ConfigError
from dsteleop.robot.placement import Placement
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import (
    SourceSpec,
    VideoFileSource,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Built:
    """A ready loop and what the caller may need beside it.

    Attributes:
        loop: the loop (not running yet; a live source starts with its first tick).
        source: the resolved source.
        video: the video file behind the hand, when the source is one (its `partial`,
            `end_note()` once it ended).
        outputs: the outputs opened for the loop, by name (`app.outputs`), in the
            registry's order.
    """

    loop: TeleopLoop
    source: SourceSpec
    video: VideoFileSource | None = None
    outputs: dict[str, Output] = field(default_factory=dict)

    def close(self) -> None:
        """Close the loop (the recording, the source, the robot), then each output (a live
        dataset's last episodes written, the Rerun log flushed), in order."""
        try:
            self.loop.close()
        finally:
            _close_all(list(self.outputs.values()))

    def summaries(self) -> dict[str, Any]:
        """What each output says it wrote, by name (those with something to say)."""
        said = {name: out.summary() for name, out in self.outputs.items()}
        return {name: s for name, s in said.items() if s is not None}


def _close_all(outputs: list[Output]) -> None:
    """Close every output, in order, each even when an earlier one failed."""
    if not outputs:
        return
    try:
        outputs[0].close()
    finally:
        _close_all(outputs[1:])


def placed_mapping(mapping: MappingConfig, placement: Placement) -> MappingConfig:
    """The camera -> robot mapping for a scene stood at `placement` (`robot.placement`):
    the neutral palm pose and the workspace box (its corners' bounding box) move and
    turn with the scene, so the operator's hand still covers the holder and the bin. The
    identity (the shipped robots) leaves the mapping as it is."""
    if placement.identity:
        return mapping
    lo, hi = np.array(mapping.workspace_min_m), np.array(mapping.workspace_max_m)
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    placed = np.array([placement.point(c) for c in corners])

    def vec(a: Any) -> tuple[float, float, float]:
        return (float(a[0]), float(a[1]), float(a[2]))

    return dataclasses.replace(
        mapping,
        neutral_position_m=vec(placement.point(np.array(mapping.neutral_position_m))),
        neutral_rotvec_rad=vec(
            so3_log(placement.rotation(so3_exp(np.array(mapping.neutral_rotvec_rad))))
        ),
        workspace_min_m=vec(placed.min(0)),
        workspace_max_m=vec(placed.max(0)),
    )


def hand_mapping(fields: dict[str, Any]) -> MappingConfig | None:
    """The hand's workspace mapping from its fields (`HandInput.mapping_config`, the
    dataclass's own fields); None for a source without one (what a viewer shows)."""
    return MappingConfig(**fields) if fields else None


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
    spec = options.source
    source_kind = sources.kind(spec.kind)
    if source_kind.resolve is not None:  # `auto`: a camera, else the demo
        spec = source_kind.resolve(spec)
        source_kind = sources.kind(spec.kind)
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
    # A source's world sets what the command line did not (the demo person's operator world,
    # docs/operator.md: the task's goal noise and the link's command delay). A robot that
    # infers its goal takes no goal noise from it: it perceives the candidates through its
    # camera (`robot.perception`: the world's 2 cm along the camera's ray only, 5 mm across).
    defaults = source_kind.defaults(options.seed)
    goal_noise_m = options.goal_noise_m
    if goal_noise_m is None and not options.infer:
        goal_noise_m = defaults.goal_noise_m
    delay_s = defaults.input_delay_s
    if delay_s is not None and not options.input_delay_given and options.loop.input_delay_s == 0:
        options = dataclasses.replace(
            options, loop=dataclasses.replace(options.loop, input_delay_s=delay_s)
        )
    asked = [k for k in output_registry.registered() if k.name in options.outputs]
    task_options: dict[str, Any] = {
        "utensil": options.utensil,
        "infer": options.infer,
        "seed": options.seed,
        "goal_noise_m": goal_noise_m,
        "export_scene": export_scene or any(k.wants_scene for k in asked),
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
    if isinstance(task, KitchenTask):  # the hand's neutral and box stand with the scene
        mapping = placed_mapping(mapping, task.env.placement)
    opened_outputs: dict[str, Output] = {}
    try:
        task.reset()
        start = robot.reset(0.0).X
        opened = source_kind.open(
            spec,
            SourceContext(
                task,
                start,
                mapping,
                options.loop.arbitration,
                realtime,
                options.seed,
                options.loop.input_delay_s,
                rotate=options.rotate,
                loop_video=options.loop_video,
                change_mind=options.change_mind,
            ),
        )
        context = OutputContext(
            task,
            options.loop.rate_hz,
            options.record,
            source_kind.pixels,
            frames=source_kind.pixels and output_registry.FRAMES in options.outputs,
        )
        frames = opened.frames
        for k in asked:
            out = k.open(options.outputs[k.name], context)
            if out is not None:
                opened_outputs[k.name] = out
                if frames is not None:
                    frames = out.wrap_source(frames)
        delay = options.loop.input_delay_s
        hand: HandInput
        if opened.hand is not None:  # an input of its own, not a camera
            hand = opened.hand
        elif realtime:
            assert frames is not None
            # Opened (and the model loaded) now; capture starts with the loop's first tick,
            # so a video plays from its first frame.
            stream = TrackingStream(frames, HandTracker()).open()
            hand = TrackedHandInput.from_stream(stream, WorkspaceMapping(mapping), delay)
        else:
            assert frames is not None
            hand = TrackedHandInput.from_source(
                frames, HandTracker(), WorkspaceMapping(mapping), delay, t0_s=0.0
            )
        history = None if options.history is None else HistoryFile(options.history)
        meta: dict[str, Any] = {"source_kind": spec.kind, "seed": options.seed}
        loop = TeleopLoop(
            options.loop,
            hand,
            robot,
            task,
            clock=MonotonicClock() if realtime else ManualClock(0.0),
            observers=(*opened.observers, *observers),
            history_file=history,
            outputs=tuple(opened_outputs.values()),
            record_root=record_root,
            meta=meta,
        )
    except BaseException:
        try:
            robot.close()
            task.close()
        finally:
            _close_all(list(opened_outputs.values()))
        raise
    return Built(loop, spec, opened.video, opened_outputs)
