"""Bench group `export`: a 60 s session with a camera exported as a LeRobot dataset.

The session is made first (not timed): the demo operator recorded headless for 60 s of loop
time (trials of 10 s, the task reset 1 s after each outcome, so it holds several episodes),
and a camera video beside it as `--record-video` writes one (the session's own crash-safe
H.264 writer, a frame at each tick's time, `frames.jsonl`): the frames of a real hand video
from the test data, looping, when it is given (`--data DIR`), else a synthetic moving
pattern of the webcam's usual 640 x 480. Then `export --to lerobot` of the session is timed,
with each camera codec in turn (AV1, LeRobot's own default; H.264, ours), alternately, `REPEATS`
times each; the figure is the recorded time over the wall time of the whole export (reading,
decoding, re-encoding, the tables, the statistics), `speed_x_realtime`, its median; the
recorded time is the episodes' ticks (about 55 of the 60 s: the ticks between an outcome and
the next reset belong to no episode). The target is 10x real time. `machine` (CPU model,
cores, load) is reported by the command.
"""

from __future__ import annotations

import logging
import os
import statistics
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.bench import data_dir

log = logging.getLogger(__name__)

SESSION_S = 60.0
REPEATS = 3
TARGET_X = 10.0
VIDEO = "open_hand_wave_landscape.mp4"


def _frames(n: int) -> tuple[list[Any], str]:
    """`n` camera images (BGR): a real hand video's frames looping, or a synthetic pattern."""
    data = data_dir()
    video = None if data is None else data / "videos" / VIDEO
    if video is not None and video.is_file():
        import av

        with av.open(str(video)) as c:
            src = [f.to_ndarray(format="bgr24") for f in c.decode(c.streams.video[0])]
        return [src[k % len(src)] for k in range(n)], f"{VIDEO} (looping)"
    y, x = np.mgrid[0:480, 0:640]
    out = []
    for k in range(n):
        img = np.empty((480, 640, 3), dtype=np.uint8)
        img[..., 0] = (x + 3 * k) % 256
        img[..., 1] = (y + 2 * k) % 256
        img[..., 2] = ((x + y) // 2 + k) % 256
        out.append(img)
    return out, "synthetic 640x480"


def make_session(folder: Path, seconds: float = SESSION_S) -> str:
    """Record the demo for `seconds` of loop time into `folder`, with a camera video beside
    it (module docstring); returns what the frames are."""
    import json

    from dsteleop.app.compose import LoopOptions, build
    from dsteleop.app.loop import LoopConfig
    from dsteleop.app.session.video import FRAMES, Mp4Writer
    from dsteleop.app.session.video import VIDEO as SESSION_VIDEO
    from dsteleop.arbitration import Mode

    options = LoopOptions.of("demo", LoopConfig(mode=Mode.DS, reset_after_s=1.0), time_limit_s=10.0)
    built = build(options, realtime=False)
    loop = built.loop
    rate = loop.config.rate_hz
    n = round(seconds * rate)
    try:
        loop.start_recording(folder)
        for k in range(n):
            loop.clock.sleep_until(k / rate)
            loop.tick(k / rate)
    finally:
        built.close()
    images, what = _frames(n)
    h, w = images[0].shape[:2]
    writer = Mp4Writer(folder / SESSION_VIDEO, rate, w, h)
    try:
        with open(folder / FRAMES, "w", encoding="utf-8") as index:
            for k, img in enumerate(images):
                writer.write(img)
                index.write(json.dumps({"i": k, "seq": k, "t_capture": k / rate}) + "\n")
    finally:
        writer.close()
    return what


def run(quick: bool = False) -> dict[str, Any]:
    from dsteleop.app.lerobot.export import export, plan

    seconds = 10.0 if quick else SESSION_S
    repeats = 1 if quick else REPEATS
    with tempfile.TemporaryDirectory(prefix="dsteleop-bench-export-") as tmp:
        session = Path(tmp) / "session"
        frames = make_session(session, seconds)
        checked = plan([session], None, "all")
        runs: dict[str, list[dict[str, Any]]] = {"av1": [], "h264": []}
        for r in range(repeats):
            for codec in ("av1", "h264"):  # alternately: the load changes under both alike
                out = Path(tmp) / f"ds-{codec}-{r}"
                runs[codec].append(export([], out, checked=checked, codec=codec))
                runs[codec][-1]["load_average"] = [round(x, 2) for x in os.getloadavg()]
        result: dict[str, Any] = {
            "session_s": seconds,
            # What the export writes: the episodes' ticks (those between an outcome and the
            # next reset belong to none); the speed is of these seconds.
            "episodes_s": round(checked.ticks / checked.fps, 3),
            "episodes": checked.episodes,
            "frames": checked.ticks,
            "camera": frames,
            "target_x_realtime": TARGET_X,
        }
        for codec, rs in runs.items():
            speeds = [float(x["speed_x_realtime"]) for x in rs]
            walls = [float(x["wall_s"]) for x in rs]
            result[codec] = {
                "speed_x_realtime_median": round(statistics.median(speeds), 2),
                "speed_x_realtime": speeds,
                "wall_s": walls,
                "load_average": [x["load_average"] for x in rs],
                "meets_target": statistics.median(speeds) >= TARGET_X,
            }
    return {"export": result}
