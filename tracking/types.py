"""The data that crosses the tracking seams: frames, raw detections and tracked samples.

Frames of the camera: x right, y down, z forward along the optical axis (OpenCV's), metres.
Image landmarks are normalised like MediaPipe's: x and y in [0, 1] of the image width and
height, z the depth relative to the wrist on roughly the scale of x. World landmarks are
metres in camera-aligned axes, centred on the hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.tracking.landmarks import check_landmarks

Array = NDArray[np.float64]
Image = NDArray[np.uint8]
Handedness = Literal["Left", "Right"]


def other_hand(hand: Handedness) -> Handedness:
    """The other hand's label."""
    return "Left" if hand == "Right" else "Right"


@dataclass(frozen=True)
class Detection:
    """One hand found in one frame, before any filtering.

    Attributes:
        landmarks_image: (21, 3) normalised image landmarks (see module docstring).
        landmarks_world: (21, 3) hand-centred landmarks [m] in camera-aligned axes, or None
            when the detector gives none.
        handedness: the anatomical hand ("Left" or "Right"), already corrected for whether
            the image is mirrored.
        score: handedness/presence confidence in [0, 1].
    """

    landmarks_image: Array
    landmarks_world: Array | None
    handedness: Handedness
    score: float

    def __post_init__(self) -> None:
        check_landmarks(self.landmarks_image, "landmarks_image")
        if self.landmarks_world is not None:
            check_landmarks(self.landmarks_world, "landmarks_world")


@dataclass(frozen=True)
class Frame:
    """One frame of a hand source.

    Attributes:
        seq: frame number of the source, from 0.
        t_capture_s: capture time [s]: `time.monotonic()` for live and paced sources, the
            source's own clock (frame index / fps) for sources read as fast as possible.
        width_px: image width [px].
        height_px: image height [px].
        image: BGR pixels (height, width, 3), or None for a source that yields landmarks
            directly (the synthetic operator).
        detections: landmarks already known for this frame (synthetic operator), or None
            when a detector must find them in `image`.
    """

    seq: int
    t_capture_s: float
    width_px: int
    height_px: int
    image: Image | None = None
    detections: tuple[Detection, ...] | None = None


@dataclass(frozen=True)
class HandSample:
    """The tracked hand in one frame: the output of the tracking pipeline.

    Poses are in the physical camera frame (x right, y down, z forward), whatever the image
    mirroring. When `detected` is False the pose fields hold the last filtered values (or
    NaN before the first detection) and must not drive a robot.

    Attributes:
        seq: frame number of the source.
        t_capture_s: capture time [s] (see `Frame`).
        t_tracked_s: `time.monotonic()` when tracking of this frame finished [s].
        detected: a hand was found and selected in this frame.
        handedness: anatomical hand of the tracked hand, or None.
        score: detection confidence in [0, 1] (0 when not detected).
        landmarks_image: (21, 3) normalised image landmarks of the selected hand, or None.
        landmarks_world: (21, 3) hand-centred world landmarks [m], or None.
        p_cam_palm_m: (3,) filtered palm centre in the camera frame [m].
        R_cam_palm: (3, 3) filtered palm orientation (see `pose.py` for the palm frame).
        openness: (5,) filtered openness, thumb to little finger, in [0, 1], 1 = straight.
        raw_p_cam_palm_m: (3,) unfiltered palm centre [m] (NaN when not detected).
        raw_R_cam_palm: (3, 3) unfiltered palm orientation (NaN when not detected).
        raw_openness: (5,) unfiltered openness (NaN when not detected).
        width_px: image width [px].
        height_px: image height [px].
        image: the frame's BGR pixels, attached by the live `TrackingStream` for a viewer
            (None otherwise: headless runs keep thousands of samples and no pixels).
    """

    seq: int
    t_capture_s: float
    t_tracked_s: float
    detected: bool
    handedness: Handedness | None
    score: float
    landmarks_image: Array | None
    landmarks_world: Array | None
    p_cam_palm_m: Array
    R_cam_palm: Array
    openness: Array
    raw_p_cam_palm_m: Array
    raw_R_cam_palm: Array
    raw_openness: Array
    width_px: int
    height_px: int
    image: Image | None = None

    @property
    def has_pose(self) -> bool:
        """True when the filtered pose is finite (a hand was seen at least once)."""
        return bool(
            np.isfinite(self.p_cam_palm_m).all()
            and np.isfinite(self.R_cam_palm).all()
            and np.isfinite(self.openness).all()
        )
