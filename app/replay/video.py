"""Tracked video as loop input: replay a video file as a session, or re-track a session.

The video is tracked once, every frame, as fast as possible (MediaPipe on each frame), and
the samples then drive a fresh loop per mode through the same mapping and re-anchoring as a
live camera (`inputs.tracked.replayed_samples`), at 30 Hz ticks on the video's own clock.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.inputs.tracked import replayed_samples
from dsteleop.app.loop import LoopConfig
from dsteleop.app.replay.core import RunSink, run_headless, session_config, simulated_plant
from dsteleop.app.session.reader import Session
from dsteleop.app.session.trace import Trace
from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import InputError
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, iter_samples
from dsteleop.tracking.sources import VideoFileSource
from dsteleop.tracking.types import HandSample


def track_video(path: Path, t_capture_s: Sequence[float] | None = None) -> list[HandSample]:
    """Every frame of a video through the tracker; capture times from the video's frame
    rate, or from `t_capture_s` (one per frame) when given."""
    tracker = HandTracker()
    samples: list[HandSample] = []
    try:
        for _frame, s in iter_samples(VideoFileSource(path, realtime=False), tracker, prefetch=2):
            samples.append(s)
    finally:
        tracker.close()
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
    sink_for: Callable[[Mode], RunSink] | None = None,
) -> tuple[list[Trace], float]:
    """Track a video and run it as a session in each mode (with `arbitration`, default the
    defaults); returns (traces, duration [s]). `sink_for(mode)` gets each run's records."""
    samples = track_video(path)
    if not samples:
        raise InputError(f"{path}: no frames")
    duration = samples[-1].t_capture_s - samples[0].t_capture_s
    cfg0 = LoopConfig(arbitration=arbitration or ArbitrationConfig())
    n = int(duration * cfg0.rate_hz) + 1
    ticks = [samples[0].t_capture_s + k / cfg0.rate_hz for k in range(n)]
    traces = []
    for mode in modes:
        hand = replayed_samples(samples, WorkspaceMapping(MappingConfig()), "tracked video")
        sink = None if sink_for is None else sink_for(mode)
        plant = simulated_plant({}, export_scene=sink is not None)
        traces.append(
            run_headless(path.name, hand, ticks, cfg0.replace(mode=mode), plant, sink=sink)
        )
    return traces, duration


def replay_retracked(
    session: Session, modes: Sequence[Mode], sink_for: Callable[[Mode], RunSink] | None = None
) -> list[Trace]:
    """Re-run tracking on the session's video, then the loop in each mode (`sink_for(mode)`
    gets each run's records)."""
    video, frames = session.video, session.frames
    if video is None or frames is None:
        raise InputError(f"{session.folder}: no video.mp4 + frames.jsonl to re-track")
    times = [
        float(json.loads(line)["t_capture"])
        for line in frames.read_text().splitlines()
        if line.strip()
    ]
    samples = track_video(video, times)
    mapping = MappingConfig(**_mapping_kwargs(session.meta.get("mapping", {})))
    ticks = [r.t_s for r in session.records]
    traces = []
    for m in modes:
        sink = None if sink_for is None else sink_for(m)
        traces.append(
            run_headless(
                session.name,
                replayed_samples(samples, WorkspaceMapping(mapping), "re-tracked video"),
                ticks,
                session_config(session, m),
                simulated_plant(session.meta.get("plant", {}), export_scene=sink is not None),
                session.history,
                sink,
            )
        )
    return traces


def _mapping_kwargs(d: dict[str, Any]) -> dict[str, Any]:
    names = {f.name for f in dataclasses.fields(MappingConfig)}
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names}
