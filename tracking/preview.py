"""Drawing of tracked samples on frames, and the preview video writer (cv2, on first use).

Drawn per frame: the selected hand's skeleton, the palm frame (x red, y green, z blue, 5 cm
axes projected with the tracker's intrinsics), and one bar per finger's filtered openness.
Frames without pixels (the synthetic operator) are drawn on a grey canvas.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.errors import InputError
from dsteleop.tracking.landmarks import CONNECTIONS, FINGER_NAMES
from dsteleop.tracking.pose import CameraIntrinsics
from dsteleop.tracking.types import Frame, HandSample, Image

_AXIS_M = 0.05
_AXIS_BGR = ((0, 0, 255), (0, 200, 0), (255, 0, 0))


def _cv2() -> Any:
    return importlib.import_module("cv2")


def draw_sample(frame: Frame, sample: HandSample, intrinsics: CameraIntrinsics) -> Image:
    """A copy of the frame's image (or a grey canvas) with the sample drawn on it."""
    cv2 = _cv2()
    if frame.image is not None:
        canvas: Image = frame.image.copy()
    else:
        canvas = np.full((frame.height_px, frame.width_px, 3), 60, dtype=np.uint8)
    w, h = frame.width_px, frame.height_px
    if sample.detected and sample.landmarks_image is not None:
        pts = np.round(sample.landmarks_image[:, :2] * (w, h)).astype(int)
        for a, b in CONNECTIONS:
            cv2.line(canvas, tuple(pts[a]), tuple(pts[b]), (255, 255, 255), 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(canvas, tuple(p), 3, (0, 140, 255), -1, cv2.LINE_AA)
    if sample.has_pose and sample.p_cam_palm_m[2] > 0:
        p = sample.p_cam_palm_m
        ends = p + _AXIS_M * sample.R_cam_palm.T  # rows: tips of the x, y, z axes
        pix = intrinsics.project(np.vstack([p, ends]))
        if np.isfinite(pix).all() and (ends[:, 2] > 0).all():
            o = tuple(np.round(pix[0]).astype(int))
            for k in range(3):
                tip = tuple(np.round(pix[k + 1]).astype(int))
                cv2.line(canvas, o, tip, _AXIS_BGR[k], 3, cv2.LINE_AA)
        for k, name in enumerate(FINGER_NAMES):
            x0, y0 = 10 + 34 * k, h - 10
            cv2.rectangle(canvas, (x0, y0 - 80), (x0 + 24, y0), (40, 40, 40), -1)
            top = y0 - round(80 * float(np.clip(sample.openness[k], 0.0, 1.0)))
            cv2.rectangle(canvas, (x0, top), (x0 + 24, y0), (80, 220, 80), -1)
            cv2.putText(
                canvas, name[0], (x0 + 6, y0 - 84), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255)
            )
    label = f"{sample.handedness} {sample.score:.2f}" if sample.detected else "no hand"
    cv2.putText(canvas, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
    return canvas


class PreviewWriter:
    """Writes drawn frames to an MP4 file (mp4v codec).

    Args:
        path: output file (its folder must exist).
        fps: frame rate of the video [Hz].
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = fps
        self._writer: Any = None
        if not self.path.parent.is_dir():
            raise InputError(f"folder of the preview does not exist: {self.path.parent}")

    def write(self, image: Image) -> None:
        """Append one BGR image (the first fixes the video size)."""
        cv2 = _cv2()
        if self._writer is None:
            h, w = image.shape[:2]
            self._writer = cv2.VideoWriter(
                str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (w, h)
            )
            if not self._writer.isOpened():
                raise InputError(f"cannot write preview video: {self.path}")
        self._writer.write(image)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
