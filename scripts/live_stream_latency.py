"""Why the camera thread uses VIDEO mode: the time from handing MediaPipe a frame to having its
landmarks, VIDEO mode (`detect_for_video`, returns on the calling thread) against LIVE_STREAM
mode (`detect_async`, the result arrives in a callback on a MediaPipe thread).

Two `HandLandmarker`s built from the model shipped in the package, fed the same decoded
frames of a test video alternately (frame i to one, then to the other, the order swapped
every frame, so that both see the same load); LIVE_STREAM is given the next frame only after
its callback for the previous one ran, so it drops none. Prints the median and p95 per mode
[ms] and the median of the per-frame differences (LIVE_STREAM - VIDEO).

    .venv/bin/python scripts/live_stream_latency.py ../shared/data/videos/webcam_fist_thumb.mp4
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("video", type=Path)
    parser.add_argument("--max-frames", type=int, default=300)
    args = parser.parse_args()
    sys.path.insert(0, str(REPO))
    import cv2

    from dsteleop.tracking import VideoFileSource
    from dsteleop.tracking.models import hand_model_bytes
    from dsteleop.tracking.pipeline import iter_frames

    mp = importlib.import_module("mediapipe")
    vision = importlib.import_module("mediapipe.tasks.python.vision")
    base = importlib.import_module("mediapipe.tasks.python").BaseOptions
    model = hand_model_bytes()
    frames = [f.image for f in iter_frames(VideoFileSource(args.video))][: args.max_frames]
    rgbs = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in frames if f is not None]

    done = threading.Event()
    arrived: list[float] = []

    def on_result(result: Any, image: Any, t_ms: int) -> None:
        arrived.append(time.perf_counter())
        done.set()

    def options(mode: Any, **extra: Any) -> Any:
        return vision.HandLandmarkerOptions(
            base_options=base(model_asset_buffer=model), running_mode=mode, num_hands=1, **extra
        )

    video = vision.HandLandmarker.create_from_options(options(vision.RunningMode.VIDEO))
    live = vision.HandLandmarker.create_from_options(
        options(vision.RunningMode.LIVE_STREAM, result_callback=on_result)
    )
    ms_video: list[float] = []
    ms_live: list[float] = []
    for i, rgb in enumerate(rgbs):
        t_ms = 1000 * (i + 1) // 30
        for mode in ("video", "live") if i % 2 == 0 else ("live", "video"):
            image = mp.Image(image_format=mp.ImageFormat.SRGB, data=rgb)
            t0 = time.perf_counter()
            if mode == "video":
                video.detect_for_video(image, t_ms)
                ms_video.append(1e3 * (time.perf_counter() - t0))
            else:
                done.clear()
                live.detect_async(image, t_ms)
                if not done.wait(5.0):
                    sys.exit(f"no LIVE_STREAM result for frame {i}")
                ms_live.append(1e3 * (arrived[-1] - t0))
    video.close()
    live.close()
    a, b = np.array(ms_video[1:]), np.array(ms_live[1:])  # the first frame loads the graph
    out = {
        "video": args.video.name,
        "frames": len(a),
        "mediapipe": mp.__version__,
        "load": [round(x, 2) for x in os.getloadavg()],
        "video_mode_ms": {
            "median": round(float(np.median(a)), 2),
            "p95": round(float(np.percentile(a, 95)), 2),
        },
        "live_stream_ms": {
            "median": round(float(np.median(b)), 2),
            "p95": round(float(np.percentile(b, 95)), 2),
        },
        "live_minus_video_ms_median": round(float(np.median(b - a)), 2),
    }
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
