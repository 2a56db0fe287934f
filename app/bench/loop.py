"""Bench group `loop`: the live loop at 30 Hz with tracking on a real video and the robot.

Runs `TeleopLoop` in real time on the monotonic clock for 60 s (10 s with --quick), after a
2 s warm-up that is not counted (the model loads on the first frames): capture
and MediaPipe tracking of a real hand video (paced at its frame rate, looping) in their own
threads, DS arbitration and the PyBullet robot in the loop, each tick following the video's
frames (`timing.RateClock`). Reports start-time jitter (p50/p99/max), tick duration, overruns,
the rate kept (ticks per second of the measured wall time), the share of ticks that started
on a new frame, and, over the same frames, frame-to-command latency (capture of a frame to
the robot command computed from it; p50/p95/p99), the tracker's time per frame (capture to
tracked) and MediaPipe's own time per frame (its `detect` call alone), with
`latency_over_mediapipe_ms_p50` the difference of the two medians (issue 24's target: at most
5 ms). Falls back to the demo source when the test-data folder is not given (`--data DIR`,
docs/test-data.md).

`loop_fixed_rate` is the same run on the fixed-rate schedule (the loop before it followed the
camera), measured right after `loop`, for the comparison under the same load.

A second run, `loop_recording_video`, measures the same while the session is recorded, as
`run --record DIR --record-video` does: every tick to `ticks.jsonl` (recorder thread) and
every camera frame to the crash-safe `video.mp4` (H.264, its own writer thread), into a
temporary folder that is removed afterwards.

`loop_rerun` measures it with a Rerun logger writing the run to a file, as `--rerun
FILE.rrd` does (the scene's poses exported every tick, the logger's thread sending columns
twice a second, camera frames at up to 10 Hz), and `loop_rerun_absent_viewer` with a logger
streaming to a viewer that is not there (`--rerun-connect` to a port nothing listens on):
each reports what the logger logged and dropped (and the file's size).
"""

from __future__ import annotations

import socket
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.bench import data_dir
from dsteleop.app.inputs.tracked import TrackedHandInput
from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.loop.timing import raise_priority
from dsteleop.app.outputs.rerun import RerunOutput
from dsteleop.app.outputs.video import VideoOutput
from dsteleop.app.plants.kitchen import simulated_kitchen
from dsteleop.app.rrd.target import RerunTarget
from dsteleop.app.session.video import FrameRecorder
from dsteleop.arbitration import Mode
from dsteleop.tracking.detector import DetectorConfig, HandDetector, make_detector
from dsteleop.tracking.mapping import WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import FrameSource, VideoFileSource
from dsteleop.tracking.types import Detection, Image

VIDEO = "open_hand_wave_landscape.mp4"


def shared_video() -> Path | None:
    """The test video, when the test-data folder is given (docs/test-data.md)."""
    data = data_dir()
    p = None if data is None else data / "videos" / VIDEO
    return p if p is not None and p.is_file() else None


def run(quick: bool = False) -> dict[str, Any]:
    seconds = 10.0 if quick else 60.0
    raise_priority()  # as `dsteleop serve` does
    out = {"loop": _one(seconds, record=False)}
    out["loop_fixed_rate"] = _one(seconds, follow=False)
    with tempfile.TemporaryDirectory(prefix="dsteleop-bench-") as tmp:
        out["loop_recording_video"] = _one(seconds, record=True, folder=Path(tmp) / "session")
        out["loop_rerun"] = _one(seconds, rerun=RerunTarget(Path(tmp) / "bench.rrd"))
    out["loop_rerun_absent_viewer"] = _one(seconds, rerun=RerunTarget(connect=_unused_address()))
    return out


def _unused_address() -> str:
    """A viewer address on a local port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"rerun+http://127.0.0.1:{port}/proxy"


def _one(
    seconds: float,
    record: bool = False,
    folder: Path | None = None,
    rerun: RerunTarget | None = None,
    follow: bool = True,
) -> dict[str, Any]:
    """One measured run (module docstring), recording into `folder` when `record`, with a
    Rerun logger when `rerun` is given, following the frames unless not `follow`."""
    video = shared_video()
    if video is None:
        from dsteleop.app.compose import LoopOptions, build

        asked = {} if rerun is None else {"rerun": rerun}
        built = build(
            LoopOptions.of("demo", LoopConfig(mode=Mode.DS), outputs=asked), realtime=True
        )
        built.loop.follow_frames = follow
        result = _measure(built.loop, seconds, "demo (synthetic operator, no pixels)", folder)
        out = built.outputs.get("rerun")
        if isinstance(out, RerunOutput) and rerun is not None:
            result["rerun"] = _rerun_stats(out.logger, rerun)
        return result
    robot, task = simulated_kitchen(utensil="spoon", seed=0, export_scene=rerun is not None)
    source: FrameSource = VideoFileSource(video, realtime=True, loop=True)
    recorded = VideoOutput() if record else None  # the frames into each session
    if recorded is not None:
        source = recorded.wrap_source(source)
    detector = _TimedDetector(make_detector(DetectorConfig()))
    stream = TrackingStream(source, HandTracker(detector=detector))
    hand = TrackedHandInput.from_stream(stream.open(), WorkspaceMapping())
    logger: Any = None
    if rerun is not None:
        from dsteleop.app.rrd.live import RerunLogger

        task.reset()  # the scene and the goals exist once the task is set up
        logger = RerunLogger(rerun, "bench", task.scene(), task.describe())
    loop = TeleopLoop(
        LoopConfig(mode=Mode.DS),
        hand,
        robot,
        task,
        outputs=() if recorded is None else (recorded,),
        observers=() if logger is None else (logger,),
        follow_frames=follow,
    )
    what = f"video {video.name} (looping, MediaPipe full model)"
    frames = None if recorded is None else recorded.recorder
    result = _measure(loop, seconds, what, folder, frames, detector=detector)
    if logger is not None:
        result["rerun"] = _rerun_stats(logger, rerun)
    return result


class _TimedDetector:
    """A `HandDetector` that keeps the time of each of its `detect` calls [ms]."""

    def __init__(self, inner: HandDetector) -> None:
        self.inner = inner
        self.ms: list[float] = []

    def detect(self, image_bgr: Image, t_s: float) -> list[Detection]:
        t0 = time.perf_counter()
        out = self.inner.detect(image_bgr, t_s)
        self.ms.append((time.perf_counter() - t0) * 1e3)
        return out

    def close(self) -> None:
        self.inner.close()


def _rerun_stats(logger: Any, target: RerunTarget | None) -> dict[str, Any]:
    stats = logger.close()
    path = None if target is None else target.path
    size = path.stat().st_size if path is not None and path.is_file() else 0
    return {**stats, "file_mb": round(size / 1e6, 2), "connect": target and target.connect}


def _measure(
    loop: TeleopLoop,
    seconds: float,
    source: str,
    folder: Path | None = None,
    frames: FrameRecorder | None = None,
    warmup_s: float = 2.0,
    detector: _TimedDetector | None = None,
) -> dict[str, Any]:
    recorded: dict[str, Any] = {}
    mediapipe: dict[str, Any] = {}
    try:
        # Warm-up: the first frames load the model and fill caches; then measure.
        loop.run(max_ticks=round(warmup_s * loop.config.rate_hz))
        if folder is not None:
            loop.start_recording(folder)  # resets the task: a new episode, as a user's would
        loop.rate.reset_stats()
        loop.latency_ms.clear()
        loop.tracking_ms.clear()
        if detector is not None:
            detector.ms.clear()
        t0 = time.monotonic()
        loop.run(max_ticks=round(seconds * loop.config.rate_hz))
        wall_s = time.monotonic() - t0
        summary = loop.timing_summary()
        if detector is not None and detector.ms:
            mp = float(np.median(detector.ms))
            mediapipe = {
                "mediapipe_frames": len(detector.ms),
                "mediapipe_ms_p50": round(mp, 3),
                "mediapipe_ms_p95": round(float(np.percentile(detector.ms, 95)), 3),
            }
            if "latency_ms_p50" in summary:
                over = float(summary["latency_ms_p50"]) - mp
                mediapipe["latency_over_mediapipe_ms_p50"] = round(over, 3)
    finally:
        loop.close()
    if folder is not None:
        video = folder / "video.mp4"
        recorded = {
            "recorded_ticks": sum(1 for _ in (folder / "ticks.jsonl").open()),
            "recorded_frames": 0 if frames is None else frames.written,
            "video_bytes_per_s": round(video.stat().st_size / seconds) if video.is_file() else 0,
        }
    return {
        "source": source,
        "seconds": seconds,
        "follows_frames": loop.follow_frames and loop.hand.arrivals is not None,
        "rate_hz_target": loop.config.rate_hz,
        "rate_hz": round(summary["ticks"] / wall_s, 3),
        **summary,
        **mediapipe,
        **recorded,
    }
