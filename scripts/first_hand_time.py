"""How long the first frames with a hand take after `HandTracker.warm_up`.

Before, `warm_up` ran only the detector (on a blank frame), and the second frame with a hand
took 0.5-2 s more: not MediaPipe but the orientation filter's compiled SO(3) maths, loaded
from numba's cache at its first call. `warm_up` now also tracks a synthetic hand twice.
Prints the warm-up time and, for the first four frames and as the median of the rest [ms],
the detector's time and the rest of `HandTracker.process` (selection, pose, filters), for the
`dsteleop` of the tree given (default: this checkout) on the first 30 frames of a video.

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
    detect_ms, rest_ms = [], []
    for frame in frames:
        t0 = time.perf_counter()
        hands = tracker.detect(frame)
        t1 = time.perf_counter()
        tracker.process_detections(frame, hands)
        detect_ms.append(1e3 * (t1 - t0))
        rest_ms.append(1e3 * (time.perf_counter() - t1))
    tracker.close()
    out = {
        "mediapipe": mediapipe.__version__,
        "warm_up_ms": round(warm_ms),
        "first_frames_detect_ms": [round(x) for x in detect_ms[:4]],
        "first_frames_rest_ms": [round(x) for x in rest_ms[:4]],
        "median_after_detect_ms": round(float(np.median(detect_ms[5:])), 1),
        "median_after_rest_ms": round(float(np.median(rest_ms[5:])), 1),
    }
    sys.stdout.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
