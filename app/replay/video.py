"""Tracked video as loop input: replay a video file as a session, or re-track a session.

The video is tracked once, every frame, as fast as possible (MediaPipe on each frame), and
the samples then drive a fresh loop per mode through the same mapping and re-anchoring as a
live camera (`inputs.tracked.replayed_samples`), at 30 Hz ticks on the video's own clock.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.inputs.tracked import replayed_samples
from dsteleop.app.loop import LoopConfig
from dsteleop.app.replay.core import SinkFor, run_headless, session_config, simulated_world
from dsteleop.app.session.episodes import Episode
from dsteleop.app.session.reader import Session
from dsteleop.app.session.trace import Trace
from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import InputError
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, iter_samples
from dsteleop.tracking.sources import VideoFileSource
from dsteleop.tracking.types import HandSample


def track_video(
    path: Path,
    t_capture_s: Sequence[float] | None = None,
    *,
    rotate: int | None = None,
    allow_partial: bool = False,
) -> list[HandSample]:
    """Every frame of a video through the tracker; capture times from the video's frame
    rate, or from `t_capture_s` (one per frame) when given.

    Args:
        path: the video.
        t_capture_s: capture time of each frame on the loop's clock [s] (a session's index).
        rotate: turn the frames [deg clockwise] (None: the container's rotation).
        allow_partial: accept a video that ends before the frames it declares.

    Raises:
        InputError: the video is partial (and that is not allowed).
    """
    tracker = HandTracker()
    samples: list[HandSample] = []
    source = VideoFileSource(path, realtime=False, rotate=rotate)
    try:
        for _frame, s in iter_samples(source, tracker, prefetch=2):
            samples.append(s)
    finally:
        tracker.close()
    if source.partial and not allow_partial:
        source.check_complete()
    if t_capture_s is not None:
        n = min(len(samples), len(t_capture_s))
        samples = [
            dataclasses.replace(s, t_capture_s=float(t), t_tracked_s=float(t))
            for s, t in zip(samples[:n], t_capture_s[:n])
        ]
    return samples


def replay_video(
    path: Path,
    modes: Sequence[Mode],
    arbitration: ArbitrationConfig | None = None,
    *,
    rotate: int | None = None,
    allow_partial: bool = False,
    sink_for: SinkFor | None = None,
    robot: str = "iiwa",
) -> tuple[list[Trace], float]:
    """Track a video and run it as a session in each mode (with `arbitration`, default the
    defaults) on the simulated `robot` (a description's name or file); returns (traces,
    duration [s]). `rotate`, `allow_partial`: `track_video`; `sink_for(name, mode)` gets each
    run's records."""
    from dsteleop.robot.description import load_description

    desc = load_description(robot)
    mapping = MappingConfig(robot_fingers=tuple((f.name, f.human) for f in desc.fingers))
    samples = track_video(path, rotate=rotate, allow_partial=allow_partial)
    if not samples:
        raise InputError(f"{path}: no frames")
    duration = samples[-1].t_capture_s - samples[0].t_capture_s
    cfg0 = LoopConfig(arbitration=arbitration or ArbitrationConfig())
    n = int(duration * cfg0.rate_hz) + 1
    ticks = [samples[0].t_capture_s + k / cfg0.rate_hz for k in range(n)]
    traces = []
    for mode in modes:
        hand = replayed_samples(samples, WorkspaceMapping(mapping), "tracked video")
        sink = None if sink_for is None else sink_for(path.name, mode)
        world = simulated_world({}, export_scene=sink is not None, robot=str(desc.path))
        traces.append(
            run_headless(path.name, hand, ticks, cfg0.replace(mode=mode), world, sink=sink)
        )
    return traces, duration


def frame_times(path: Path) -> list[float]:
    """The capture time of each recorded frame, in video order, from `frames.jsonl`; a
    line cut short by a killed process ends the list."""
    times: list[float] = []
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            times.append(float(json.loads(line)["t_capture"]))
        except (ValueError, KeyError, TypeError):
            break
    return times


def replay_retracked(
    session: Session,
    modes: Sequence[Mode],
    allow_partial: bool = False,
    sink_for: SinkFor | None = None,
) -> list[tuple[Episode, Trace]]:
    """Re-run tracking on the session's video once, then the loop on every episode in each
    mode; (episode, trace) pairs. `sink_for(episode name, mode)` gets each run's records.

    The frame index (`frames.jsonl`) says how many frames the video must hold: every line
    is written after its frame, so even a session killed mid-recording has them all.

    Raises:
        InputError: no video, or the video holds fewer frames than its index names (unless
            `allow_partial`).
    """
    video, frames = session.video, session.frames
    if video is None or frames is None:
        raise InputError(f"{session.folder}: no video.mp4 + frames.jsonl to re-track")
    times = frame_times(frames)
    samples = track_video(video, times, allow_partial=True)
    if len(samples) < len(times) and not allow_partial:
        raise InputError(
            f"{video}: read {len(samples)} of the {len(times)} frames {frames.name} names "
            "(truncated or partly unreadable); --allow-partial accepts it"
        )
    mapping = MappingConfig(**_mapping_kwargs(session.meta.get("mapping", {})))
    out = []
    for episode in session.episodes:
        view = session.of_episode(episode)
        ticks = [r.t_s for r in view.records]
        for m in modes:
            sink = None if sink_for is None else sink_for(view.name, m)
            trace = run_headless(
                view.name,
                replayed_samples(samples, WorkspaceMapping(mapping), "re-tracked video"),
                ticks,
                session_config(view, m),
                simulated_world(view.meta, export_scene=sink is not None),
                view.history,
                sink,
            )
            out.append((episode, trace))
    return out


def _mapping_kwargs(d: dict[str, Any]) -> dict[str, Any]:
    names = {f.name for f in dataclasses.fields(MappingConfig)}
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names}
