"""Tracked video as loop input: replay a video file as a session, or re-track a session.

The video is tracked once, every frame, as fast as possible (MediaPipe on each frame), and
the samples then drive a fresh loop per mode through the same mapping and re-anchoring as a
live camera (`TrackedHandInput`), at 30 Hz ticks on the video's own clock.
"""

from __future__ import annotations

import bisect
import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dsteleop.app.hand_input import TrackedHandInput
from dsteleop.app.loop import LoopConfig
from dsteleop.app.recording import Session
from dsteleop.arbitration import Mode, OperatorHistory
from dsteleop.errors import DsteleopError
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, iter_samples
from dsteleop.tracking.sources import VideoFileSource
from dsteleop.tracking.types import HandSample

if TYPE_CHECKING:
    from dsteleop.app.replay import Trace


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
        import dataclasses

        n = min(len(samples), len(t_capture_s))
        samples = [
            dataclasses.replace(s, t_capture_s=float(t), t_tracked_s=float(t))
            for s, t in zip(samples[:n], t_capture_s[:n])
        ]
    return samples


def _input(samples: list[HandSample], mapping_config: MappingConfig) -> TrackedHandInput:
    times = [s.t_capture_s for s in samples]

    def latest(now_s: float) -> HandSample | None:
        k = bisect.bisect_right(times, now_s + 1e-9) - 1
        return samples[k] if k >= 0 else None

    return TrackedHandInput(latest, WorkspaceMapping(mapping_config), description="tracked video")


def replay_video(path: Path, modes: Sequence[Mode]) -> tuple[list[Trace], float]:
    """Track a video and run it as a session in each mode; returns (traces, duration [s])."""
    from dsteleop.app.replay import run_headless

    samples = track_video(path)
    if not samples:
        raise DsteleopError(f"{path}: no frames")
    duration = samples[-1].t_capture_s - samples[0].t_capture_s
    cfg0 = LoopConfig()
    n = int(duration * cfg0.rate_hz) + 1
    ticks = [samples[0].t_capture_s + k / cfg0.rate_hz for k in range(n)]
    traces = []
    for mode in modes:
        cfg = LoopConfig(mode=mode)
        traces.append(run_headless(path.name, _input(samples, MappingConfig()), ticks, cfg, {}))
    return traces, duration


def replay_retracked(session: Session, modes: Sequence[Mode]) -> list[Trace]:
    """Re-run tracking on the session's video, then the loop in each mode."""
    from dsteleop.app.replay import _session_config, run_headless

    video = session.video
    frames = session.folder / "frames.jsonl"
    if video is None or not frames.is_file():
        raise DsteleopError(f"{session.folder}: no video.mp4 + frames.jsonl to re-track")
    times = [
        float(json.loads(line)["t_capture"])
        for line in frames.read_text().splitlines()
        if line.strip()
    ]
    samples = track_video(video, times)
    mapping = MappingConfig(**_mapping_kwargs(session.meta.get("mapping", {})))
    ticks = [float(r["t"]) for r in session.ticks]
    history = (
        OperatorHistory.from_dict(session.meta["operator_history"])
        if "operator_history" in session.meta
        else None
    )
    return [
        run_headless(
            session.name,
            _input(samples, mapping),
            ticks,
            _session_config(session, m),
            session.meta.get("plant", {}),
            history,
        )
        for m in modes
    ]


def _mapping_kwargs(d: dict[str, Any]) -> dict[str, Any]:
    import dataclasses

    names = {f.name for f in dataclasses.fields(MappingConfig)}
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names}
