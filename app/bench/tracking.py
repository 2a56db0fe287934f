"""`dsteleop bench --only tracking`: speed, smoothness and lag of the tracking pipeline.

Figures (all from many frames, medians and tail percentiles):
    tracking_fps, tracking_frame_ms   offline pipeline on the real videos resized to 640x480
                                      (480x640 for the portrait one): decode + MediaPipe
                                      HandLandmarker (shipped model) + palm pose + One Euro
                                      filters, as `dsteleop track` runs it (decoding 2 frames
                                      ahead in a reader thread); fps is frames / wall-clock
                                      seconds, frame_ms the time from asking for a frame to
                                      its sample.
    tracking_cpu_ms_per_frame         CPU time of the process (all its threads) per frame: less
                                      sensitive than fps to other programs sharing the cores.
    tracking_fps_serial, ..._serial   the same with decoding in the tracking thread.
    tracking_stage_ms                 the prefetching run split into waiting for the decoded
                                      frame, landmarks (MediaPipe) and pose + filters.
    tracking_two_hands_fps            the detector looking for 2 hands (palm detection runs on
                                      every frame that shows fewer than 2).
    tracking_detection_rate           per video.
    tracking_jitter_still             synthetic hand held still with MediaPipe-like landmark
                                      noise (1 px, 2 mm): median frame-to-frame change, raw
                                      vs filtered (position mm, rotation deg, openness).
    tracking_jitter_video             real videos: median frame-to-frame change of the palm
                                      position, raw vs filtered [mm] (the hands move, so this
                                      mixes motion and noise).
    tracking_filter_lag_ms            noise-free synthetic fast moves at 30 fps: steady lag of
                                      a 0.5 m/s translation ramp and a 3 rad/s rotation ramp
                                      (error / speed), and the delay at which the filtered
                                      position crosses the midpoint of a 0.2 m, 0.3 s
                                      minimum-jerk move.
Needs the test-data folder for the video figures (`--data DIR`, docs/test-data.md); they
are skipped, with a note, without it.
"""

from __future__ import annotations

import itertools
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.bench import data_dir, percentiles_us
from dsteleop.arbitration.se3 import HandState, so3_exp, so3_log
from dsteleop.tracking.detector import DetectorConfig
from dsteleop.tracking.pipeline import HandTracker, TrackerConfig, iter_frames, iter_samples
from dsteleop.tracking.sources import VideoFileSource
from dsteleop.tracking.synthetic import (
    LandmarkNoise,
    SyntheticSource,
    Trajectory,
    palm_facing_camera,
)
from dsteleop.tracking.types import Array

log = logging.getLogger(__name__)

VIDEOS = (
    "open_hand_wave_landscape",
    "webcam_fist_thumb",
    "webcam_two_hands",
    "portrait_fingers_open_close",
)
SIZE = (640, 480)
FPS = 30.0


def _ms(samples_s: list[float]) -> dict[str, float]:
    """median, p95, p99 [ms] of durations [s]."""
    us = percentiles_us(samples_s)
    return {k: (round(v / 1e3, 3) if k != "n" else v) for k, v in us.items()}


def _video_pass(
    videos: Path,
    names: tuple[str, ...],
    config: TrackerConfig,
    max_frames: int | None,
    prefetch: int,
) -> dict[str, Any]:
    frame_s: list[float] = []
    wait_s: list[float] = []
    detect_s: list[float] = []
    pose_s: list[float] = []
    rates: dict[str, float] = {}
    steps_raw: list[float] = []
    steps_filt: list[float] = []
    wall = cpu = 0.0
    for name in names:
        probe = VideoFileSource(videos / f"{name}.mp4")
        probe.open()
        portrait = probe.height_px > probe.width_px
        probe.close()
        # 640x480 pixels, in the video's own orientation (a portrait video is not squashed).
        src = VideoFileSource(videos / f"{name}.mp4", size=SIZE[::-1] if portrait else SIZE)
        with HandTracker(config) as tracker:
            tracker.detector  # load MediaPipe outside the timed region  # noqa: B018
            frames = iter_frames(src, prefetch)
            n = found = 0
            prev = None
            try:
                t_start, c_start = time.perf_counter(), time.process_time()
                while max_frames is None or n < max_frames:
                    t0 = time.perf_counter()
                    frame = next(frames, None)
                    if frame is None:
                        break
                    t1 = time.perf_counter()
                    dets = tracker.detect(frame)
                    t2 = time.perf_counter()
                    s = tracker.process_detections(frame, dets)
                    t3 = time.perf_counter()
                    wait_s.append(t1 - t0)
                    detect_s.append(t2 - t1)
                    pose_s.append(t3 - t2)
                    frame_s.append(t3 - t0)
                    n += 1
                    found += int(s.detected)
                    if s.detected and prev is not None and prev.detected:
                        steps_raw.append(
                            float(np.linalg.norm(s.raw_p_cam_palm_m - prev.raw_p_cam_palm_m))
                        )
                        steps_filt.append(float(np.linalg.norm(s.p_cam_palm_m - prev.p_cam_palm_m)))
                    prev = s
                wall += time.perf_counter() - t_start
                cpu += time.process_time() - c_start
            finally:
                frames.close()
        rates[name] = round(found / max(n, 1), 4)
    return {
        "fps": round(len(frame_s) / wall, 1),
        "cpu_ms_per_frame": round(1e3 * cpu / len(frame_s), 2),
        "frame_ms": _ms(frame_s),
        "stage_ms": {
            "decode_or_wait": _ms(wait_s),
            "landmarks": _ms(detect_s),
            "pose_and_filters": _ms(pose_s),
        },
        "detection_rate": rates,
        "jitter_video_mm": {
            "raw": round(1e3 * float(np.median(steps_raw)), 3),
            "filtered": round(1e3 * float(np.median(steps_filt)), 3),
        },
    }


def _synthetic(trajectory: Trajectory, duration_s: float, noise: LandmarkNoise | None) -> Any:
    src = SyntheticSource(trajectory, fps=FPS, duration_s=duration_s, noise=noise, seed=7)
    return [s for _, s in iter_samples(src, HandTracker(TrackerConfig()))]


def _still_jitter(duration_s: float) -> dict[str, Any]:
    p0, R0, g0 = np.array([0.0, 0.0, 0.5]), palm_facing_camera(), np.full(5, 0.8)

    def still(t_s: float) -> tuple[HandState, Array]:
        return HandState(p0, R0, g0), g0

    samples = _synthetic(still, duration_s, LandmarkNoise(image_px=1.0, world_m=0.002))[30:]

    def steps(get: Any, rot: bool = False) -> float:
        vals = [get(s) for s in samples]
        if rot:
            d = [np.linalg.norm(so3_log(b @ a.T)) for a, b in itertools.pairwise(vals)]
        else:
            d = [np.abs(b - a).max() for a, b in itertools.pairwise(vals)]
        return float(np.median(d))

    return {
        "position_mm": {
            "raw": round(1e3 * steps(lambda s: s.raw_p_cam_palm_m), 3),
            "filtered": round(1e3 * steps(lambda s: s.p_cam_palm_m), 3),
        },
        "rotation_deg": {
            "raw": round(float(np.degrees(steps(lambda s: s.raw_R_cam_palm, True))), 3),
            "filtered": round(float(np.degrees(steps(lambda s: s.R_cam_palm, True))), 3),
        },
        "openness_max_finger": {
            "raw": round(steps(lambda s: s.raw_openness), 4),
            "filtered": round(steps(lambda s: s.openness), 4),
        },
    }


def _lag() -> dict[str, float]:
    p0, R0, g0 = np.array([-0.15, 0.0, 0.5]), palm_facing_camera(), np.ones(5)
    v, w = 0.5, 3.0
    axis = np.array([0.0, -1.0, 0.0])

    def ramp(t_s: float) -> tuple[HandState, Array]:
        p = p0 + np.array([v * t_s, 0.0, 0.0])
        return HandState(p, so3_exp(w * t_s * axis) @ R0, g0), g0

    ramp_samples = _synthetic(ramp, 0.6, None)
    last = ramp_samples[-1]
    truth, _ = ramp(last.t_capture_s)
    lag_p = (truth.position[0] - last.p_cam_palm_m[0]) / v
    lag_r = np.linalg.norm(so3_log(truth.rotation @ last.R_cam_palm.T)) / w

    def min_jerk(t_s: float) -> tuple[HandState, Array]:
        tau = np.clip((t_s - 0.3) / 0.3, 0.0, 1.0)
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        return HandState(p0 + np.array([0.2 * s, 0.0, 0.0]), R0, g0), g0

    mj = _synthetic(min_jerk, 1.2, None)
    t = np.array([s.t_capture_s for s in mj])
    x = np.array([s.p_cam_palm_m[0] for s in mj]) - p0[0]
    t_half = float(np.interp(0.1, x, t))  # x rises monotonically
    return {
        "position_ramp_0.5mps": round(1e3 * float(lag_p), 1),
        "rotation_ramp_3radps": round(1e3 * float(lag_r), 1),
        "min_jerk_0.2m_0.3s_midpoint_delay": round(1e3 * (t_half - 0.45), 1),
    }


def run(quick: bool) -> dict[str, Any]:
    """The tracking figures (module docstring); `quick` uses fewer frames."""
    out: dict[str, Any] = {}
    data = data_dir()
    videos = Path() if data is None else data / "videos"
    if data is not None and (videos / f"{VIDEOS[0]}.mp4").is_file():
        names = VIDEOS[:1] if quick else VIDEOS
        limit = 120 if quick else None
        full = _video_pass(videos, names, TrackerConfig(), limit, prefetch=2)
        out["tracking_fps"] = full["fps"]
        out["tracking_frame_ms"] = full["frame_ms"]
        out["tracking_cpu_ms_per_frame"] = full["cpu_ms_per_frame"]
        out["tracking_stage_ms"] = full["stage_ms"]
        out["tracking_detection_rate"] = full["detection_rate"]
        out["tracking_jitter_video_mm"] = full["jitter_video_mm"]
        serial = _video_pass(videos, names, TrackerConfig(), limit, prefetch=0)
        out["tracking_fps_serial"] = serial["fps"]
        out["tracking_frame_ms_serial"] = serial["frame_ms"]
        if not quick:
            two = TrackerConfig(detector=DetectorConfig(max_num_hands=2))
            out["tracking_two_hands_fps"] = _video_pass(videos, names, two, limit, prefetch=2)[
                "fps"
            ]
    else:
        out["tracking_note"] = "no test-data folder (--data DIR): video figures skipped"
    out["tracking_size"] = f"{SIZE[0]}x{SIZE[1]}"
    out["tracking_jitter_still"] = _still_jitter(5.0 if quick else 20.0)
    out["tracking_filter_lag_ms"] = _lag()
    return out
