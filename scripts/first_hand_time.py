"""How long the first frames with a hand take after `HandTracker.warm_up` (a known stall).

`warm_up` runs the detector on a blank frame: that loads MediaPipe's graph and runs the palm
detector, but not the landmark model, which runs only once a palm has been found. Its first
run (interpreter set-up) therefore falls on the first frames with a hand. Prints the warm-up
time, the first four frames' times and the median of the rest [ms], for the `dsteleop` of the
tree given (default: this checkout) on the first 30 frames of a video.

    .venv/bin/python scripts/first_hand_time.py \
        ../shared/data/videos/portrait_fingers_open_close.mp4 [TREE]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    video = Path(sys.argv[1])
    sys.path.insert(0, sys.argv[2] if len(sys.argv) > 2 else str(REPO))
    import mediapipe

    from dsteleop.tracking import HandTracker, VideoFileSource
    from dsteleop.tracking.pipeline import iter_frames

    frames = list(iter_frames(VideoFileSource(video)))[:30]
    tracker = HandTracker()
    t0 = time.perf_counter()
    tracker.warm_up(frames[0].width_px, frames[0].height_px)
    warm_ms = 1e3 * (time.perf_counter() - t0)
    ms = []
    for frame in frames:
        t0 = time.perf_counter()
        tracker.process(frame)
        ms.append(1e3 * (time.perf_counter() - t0))
    tracker.close()
    out = {
        "mediapipe": mediapipe.__version__,
        "warm_up_ms": round(warm_ms),
        "first_frames_ms": [round(x) for x in ms[:4]],
        "median_ms_after": round(float(np.median(ms[5:])), 1),
    }
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
