"""`dsteleop track SOURCE --out FILE [--preview FILE.mp4]`: headless hand tracking.

Runs the tracking pipeline over every frame of a source (video file, image folder, camera,
or "synthetic") as fast as possible, writes one JSON record per frame (JSON Lines) and
prints one summary JSON object on stdout; logs go to stderr.

Record keys: `seq`, `t` (capture time, s), `detected`, `handedness`, `score`, `landmarks`
(21 x [x, y, z] normalised image landmarks, or null), `landmarks_world` (m, or null),
`position` (filtered palm centre, m, camera frame), `rotvec` (filtered palm orientation,
rad, camera frame), `openness` (5 filtered values, thumb..little), `raw_position`,
`raw_rotvec`, `raw_openness` (unfiltered; null when not detected), `frame_ms`.
Summary keys: `frames`, `detected`, `detection_rate`, `fps` (pipeline frames per second,
wall clock, including decoding), `jitter` (median frame-to-frame change of the filtered palm
position [m] between consecutive detected frames), `jitter_raw`, `frame_ms`, `source`,
`out`, `preview`.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app import sources
from dsteleop.app.cli.options import add_video_options, check_video_complete
from dsteleop.app.outpaths import output_file
from dsteleop.arbitration.se3 import so3_log
from dsteleop.errors import ConfigError, InputError
from dsteleop.tracking.detector import DetectorConfig
from dsteleop.tracking.pipeline import HandTracker, TrackerConfig, iter_samples
from dsteleop.tracking.pose import PoseConfig
from dsteleop.tracking.preview import PreviewWriter, draw_sample
from dsteleop.tracking.selection import HandChoice, SelectionConfig
from dsteleop.tracking.sources import (
    SOURCE_GRAMMAR,
    SourceSpec,
    VideoFileSource,
    check_rotation,
    open_source,
)
from dsteleop.tracking.types import HandSample

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackCommand:
    """Options of `dsteleop track` (see `add_arguments` for their help)."""

    source: SourceSpec
    out: Path
    preview: Path | None = None
    task_model: Path | None = None
    hand: HandChoice = "any"
    max_hands: int = 1
    mirrored: bool = False
    hfov_deg: float = 60.0
    size: tuple[int, int] | None = None
    max_frames: int | None = None
    duration_s: float | None = None
    rotate: int | None = None
    allow_partial: bool = False


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", help=SOURCE_GRAMMAR)
    parser.add_argument(
        "--out", required=True, type=output_file, help="JSON Lines output, one per frame"
    )
    parser.add_argument(
        "--preview", type=output_file, help="write an MP4 with landmarks and palm frame"
    )
    parser.add_argument(
        "--task-model",
        type=Path,
        help="a hand_landmarker.task file instead of the model shipped with dsteleop",
    )
    parser.add_argument(
        "--hand", choices=("any", "left", "right"), default="any", help="hand to follow"
    )
    parser.add_argument("--max-hands", type=int, default=1, help="hands the detector looks for")
    parser.add_argument(
        "--mirrored", action="store_true", help="frames are flipped left-right (selfie view)"
    )
    parser.add_argument("--hfov-deg", type=float, default=60.0, help="camera field of view")
    parser.add_argument("--size", metavar="WxH", help="resize frames, e.g. 640x480")
    parser.add_argument("--max-frames", type=int, help="stop after this many frames")
    parser.add_argument("--duration", type=float, help="length of a 'synthetic' run [s]")
    add_video_options(parser)


def _parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size must look like 640x480, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise ConfigError(f"--size must be positive, got {text!r}")
    return w, h


def _command(args: argparse.Namespace) -> TrackCommand:
    hands: dict[str, HandChoice] = {"any": "any", "left": "Left", "right": "Right"}
    hand = hands[args.hand]
    if args.max_hands < 1:
        raise ConfigError(f"--max-hands must be >= 1, got {args.max_hands}")
    if not (math.isfinite(args.hfov_deg) and 1.0 < args.hfov_deg < 179.0):
        raise ConfigError(f"--hfov-deg must be in (1, 179), got {args.hfov_deg}")
    source = sources.parse(args.source)
    if not sources.kind(source.kind).tracked:
        raise ConfigError(f"track reads a camera, a video, images or synthetic, not {source.kind}")
    return TrackCommand(
        source=source,
        out=args.out,
        preview=args.preview,
        task_model=args.task_model,
        hand=hand,
        max_hands=args.max_hands,
        mirrored=args.mirrored,
        hfov_deg=args.hfov_deg,
        size=_parse_size(args.size),
        max_frames=args.max_frames,
        duration_s=args.duration,
        rotate=check_rotation(args.rotate),
        allow_partial=bool(args.allow_partial),
    )


def _vec(a: np.ndarray[Any, Any] | None, digits: int = 5) -> Any:
    if a is None or not np.isfinite(a).all():
        return None
    return np.round(a, digits).tolist()


def record(sample: HandSample, frame_ms: float) -> dict[str, Any]:
    """The JSON record of one sample (module docstring)."""
    rot = so3_log(sample.R_cam_palm) if sample.has_pose else None
    raw_rot = so3_log(sample.raw_R_cam_palm) if sample.detected else None
    return {
        "seq": sample.seq,
        "t": round(sample.t_capture_s, 6),
        "detected": sample.detected,
        "handedness": sample.handedness,
        "score": round(sample.score, 4),
        "landmarks": _vec(sample.landmarks_image),
        "landmarks_world": _vec(sample.landmarks_world),
        "position": _vec(sample.p_cam_palm_m),
        "rotvec": _vec(rot),
        "openness": _vec(sample.openness, 4),
        "raw_position": _vec(sample.raw_p_cam_palm_m),
        "raw_rotvec": _vec(raw_rot),
        "raw_openness": _vec(sample.raw_openness, 4),
        "frame_ms": round(frame_ms, 3),
    }


def median_step_m(positions: list[np.ndarray[Any, Any] | None]) -> float | None:
    """Median |p_k - p_{k-1}| [m] over consecutive pairs that are both present."""
    steps = [
        float(np.linalg.norm(b - a))
        for a, b in itertools.pairwise(positions)
        if a is not None and b is not None
    ]
    return float(np.median(steps)) if steps else None


def run(args: argparse.Namespace) -> int:
    cmd = _command(args)
    log.info("track: %s", cmd)
    config = TrackerConfig(
        detector=DetectorConfig(
            task_model_path=cmd.task_model,
            max_num_hands=cmd.max_hands,
            static_images=cmd.source.kind == "images",
        ),
        pose=PoseConfig(hfov_deg=cmd.hfov_deg),
        selection=SelectionConfig(hand=cmd.hand),
        mirrored=cmd.mirrored,
    )
    source = open_source(cmd.source, size=cmd.size, duration_s=cmd.duration_s, rotate=cmd.rotate)
    # Files decode two frames ahead while MediaPipe runs; live sources never queue frames.
    prefetch = 0 if source.realtime else 2
    preview: PreviewWriter | None = None
    if cmd.preview is not None:
        preview = PreviewWriter(cmd.preview, fps=source.fps)
    filtered: list[np.ndarray[Any, Any] | None] = []
    raw: list[np.ndarray[Any, Any] | None] = []
    frame_s: list[float] = []
    n = n_detected = 0
    t_start = time.perf_counter()
    try:
        with HandTracker(config) as tracker, cmd.out.open("w", encoding="utf-8") as out:
            t_prev = time.perf_counter()
            for frame, sample in iter_samples(source, tracker, cmd.max_frames, prefetch):
                t_now = time.perf_counter()
                frame_s.append(t_now - t_prev)
                n += 1
                n_detected += int(sample.detected)
                filtered.append(sample.p_cam_palm_m if sample.detected else None)
                raw.append(sample.raw_p_cam_palm_m if sample.detected else None)
                out.write(json.dumps(record(sample, 1e3 * frame_s[-1])) + "\n")
                if preview is not None:
                    k = tracker.intrinsics(frame.width_px, frame.height_px)
                    preview.write(draw_sample(frame, sample, k))
                t_prev = time.perf_counter()
    finally:
        if preview is not None:
            preview.close()
    wall = time.perf_counter() - t_start
    if n == 0:
        raise InputError(f"no frames read from {cmd.source}")
    if isinstance(source, VideoFileSource) and cmd.max_frames is None:
        check_video_complete(source, cmd.allow_partial, f"the {n} frames tracked are in {cmd.out}")
    ms = np.asarray(frame_s) * 1e3
    summary = {
        "source": source.describe(),
        "frames": n,
        "detected": n_detected,
        "detection_rate": round(n_detected / n, 4),
        "fps": round(n / wall, 2),
        "frame_ms": {
            "median": round(float(np.median(ms)), 3),
            "p95": round(float(np.percentile(ms, 95)), 3),
        },
        "jitter": median_step_m(filtered),
        "jitter_raw": median_step_m(raw),
        "out": str(cmd.out),
        "preview": None if cmd.preview is None else str(cmd.preview),
    }
    sys.stdout.write(json.dumps(summary) + "\n")
    return 0
