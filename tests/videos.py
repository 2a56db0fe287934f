"""Test videos made at test time: MP4 files from given frames, a container rotation, a cut.

Everything here writes into a test's temporary folder; the shared test data is only read.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

Image = NDArray[np.uint8]


def read_frames(path: Path, n: int | None = None, rotate: int = 0) -> list[Image]:
    """The first `n` frames of a video as stored (or turned `rotate` degrees clockwise)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)
    turn = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}
    frames: list[Image] = []
    try:
        while n is None or len(frames) < n:
            ok, img = cap.read()
            if not ok:
                break
            frames.append(np.asarray(cv2.rotate(img, turn[rotate]) if rotate else img, np.uint8))
    finally:
        cap.release()
    return frames


def write_mp4(path: Path, frames: Sequence[Image], fps: float = 30.0, crf: int = 16) -> Path:
    """An ordinary MP4 (H.264) with its index first (`faststart`), as phones and editors
    write them: cut short, it still declares every frame."""
    import av

    out: Any = av.open(str(path), "w", format="mp4", options={"movflags": "faststart"})
    try:
        stream: Any = out.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.options = {"crf": str(crf), "preset": "fast"}
        h, w = frames[0].shape[:2]
        stream.width, stream.height, stream.pix_fmt = w - w % 2, h - h % 2, "yuv420p"
        for k, img in enumerate(frames):
            even = np.ascontiguousarray(img[: h - h % 2, : w - w % 2])
            f = av.VideoFrame.from_ndarray(even, format="bgr24")
            f.pts = k
            for packet in stream.encode(f):
                out.mux(packet)
        for packet in stream.encode(None):
            out.mux(packet)
    finally:
        out.close()
    return path


def set_rotation(path: Path, deg_clockwise: int) -> None:
    """Write a display matrix into the video track's header (`tkhd`), as a phone does: a
    player turns the stored frames `deg_clockwise` degrees clockwise to show them."""
    data = bytearray(path.read_bytes())
    i = data.index(b"tkhd")
    version = data[i + 4]
    matrix_at = i + 8 + (32 if version == 1 else 20) + 16
    r = np.radians(-deg_clockwise)
    c, s = round(float(np.cos(r))), round(float(np.sin(r)))
    values = [c << 16, -s << 16, 0, s << 16, c << 16, 0, 0, 0, 1 << 30]
    data[matrix_at : matrix_at + 36] = struct.pack(">9i", *values)
    path.write_bytes(bytes(data))


def cut(path: Path, out: Path, fraction: float) -> Path:
    """The first `fraction` of a file's bytes (a truncated download)."""
    data = path.read_bytes()
    out.write_bytes(data[: int(len(data) * fraction)])
    return out
