"""Palm pose and per-finger openness from 21 hand landmarks: pure functions, no state.

Shapes: the *world shape* is MediaPipe's world landmarks (metres, camera-aligned, hand
centred). The *image shape* back-projects the image landmarks: MediaPipe's z is the depth
relative to the wrist on the scale of x, i.e. z_i W ~ fx (Z_i - Z_wrist) / Z_wrist, so with
pixels (u_i, v_i) = (x_i W, y_i H) every landmark is, exactly up to the wrist depth Z_wrist,

    P_i = Z_wrist * b_i,   b_i = (1 + z_i W / fx) * [(u_i - cx) / fx, (v_i - cy) / fy, 1].

Palm frame (camera coordinates), from the world shape (the image shape without one):
    origin  c = mean of the wrist and the four finger MCPs (`landmarks.PALM_CENTRE`);
    x_palm  from the wrist towards the fingers: unit(mid(index MCP, little MCP) - wrist);
    z_palm  unit((little MCP - wrist) x (index MCP - wrist)), made orthogonal to x_palm:
            out of the palm of a right hand, out of the back of a left hand;
    y_palm  = z_palm x x_palm, so R_cam_palm = [x_palm y_palm z_palm] is a proper rotation
            and roll, pitch and yaw of the palm are all observable.
The frame deliberately ignores the handedness label: MediaPipe's label is unreliable on some
views (the back of the hand), and a frame that depended on it would flip by 180 deg when the
label flickers. The robot mapping only uses rotations relative to a calibrated neutral pose,
so the constant difference between the hands does not matter there.

Palm position: the depth comes from the apparent palm size against a calibrated reference:
with size(.) the RMS distance of the rigid palm landmarks (`landmarks.PALM_RIGID`) from
their centroid,

    Z_wrist = palm_size_m * hand_scale / size(b),     p_cam_palm = Z_wrist * mean_c(b_i),

the mean over the palm-centre landmarks. (MediaPipe's world landmarks carry a metric scale
too, but on the test videos it shrinks by up to 2x from one view to another, while the
apparent size stays consistent, so they only give orientation and openness.)

Openness of a finger: the joint flexions are the angles between consecutive segments of its
chain (`landmarks.FINGER_CHAINS`: MCP, PIP, DIP for the fingers, MCP and IP for the thumb),
from the world shape; with theta their sum,

    openness = clip((theta_closed - theta) / (theta_closed - theta_open), 0, 1),

so 1 = straight and 0 = fully folded. Angles do not depend on hand size or distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dsteleop.errors import ConfigError, ContractError
from dsteleop.tracking.landmarks import (
    FINGER_CHAINS,
    INDEX_MCP,
    LITTLE_MCP,
    PALM_CENTRE,
    PALM_RIGID,
    WRIST,
)
from dsteleop.tracking.types import Array, Detection

_FINGER_IDX = tuple(np.asarray(chain) for chain in FINGER_CHAINS)
_PALM_CENTRE = np.asarray(PALM_CENTRE)
_PALM_RIGID = np.asarray(PALM_RIGID)


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of an undistorted camera.

    Attributes:
        width_px: image width [px].
        height_px: image height [px].
        fx_px: focal length along x [px].
        fy_px: focal length along y [px].
        cx_px: principal point x [px].
        cy_px: principal point y [px].
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    @classmethod
    def from_hfov(cls, width_px: int, height_px: int, hfov_deg: float) -> CameraIntrinsics:
        """Square pixels, centred principal point, given the horizontal field of view [deg]."""
        if not 1.0 < hfov_deg < 179.0:
            raise ConfigError(f"hfov_deg must be in (1, 179), got {hfov_deg!r}")
        if width_px <= 0 or height_px <= 0:
            raise ConfigError(f"image size must be positive, got {width_px}x{height_px}")
        f = 0.5 * width_px / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width_px, height_px, f, f, 0.5 * width_px, 0.5 * height_px)

    def project(self, points_cam_m: Array) -> Array:
        """Pixels (..., 2) of camera-frame points (..., 3) [m] (z > 0)."""
        z = points_cam_m[..., 2]
        u = self.fx_px * points_cam_m[..., 0] / z + self.cx_px
        v = self.fy_px * points_cam_m[..., 1] / z + self.cy_px
        return np.stack([u, v], -1)


@dataclass(frozen=True)
class PoseConfig:
    """Parameters of the pose and openness estimate (see module docstring).

    Attributes:
        hfov_deg: horizontal field of view of the camera [deg]; 60 is a typical webcam.
        hand_scale: operator hand size relative to the reference hand (1 = average adult);
            every depth scales with it, so it is the depth calibration.
        palm_size_m: RMS distance of the rigid palm landmarks from their centroid for the
            reference hand [m] (0.0415: the synthetic `HandModel`, an adult hand with a
            9 cm wrist to middle-finger MCP).
        theta_open_rad: per finger (thumb..little), summed joint flexion of a straight
            finger [rad]. A straight finger is never at exactly 0: the wrist -> MCP -> PIP
            angle includes the fan of the metacarpals. Typical values of MediaPipe 0.10.21's
            world landmarks on the test photos of hands (docs/test-data.md) ("four": straight
            fingers, thumb folded).
        theta_closed_rad: per finger, summed flexion of a fully folded finger [rad]
            (fists in the "none" and "rock" photos reach 3.3-4.2 rad on the fingers and
            1.1-1.7 rad on a thumb folded across the palm).
    """

    hfov_deg: float = 60.0
    hand_scale: float = 1.0
    palm_size_m: float = 0.0415
    theta_open_rad: tuple[float, float, float, float, float] = field(
        default=(0.4, 0.8, 0.6, 0.5, 0.6)
    )
    theta_closed_rad: tuple[float, float, float, float, float] = field(
        default=(1.5, 3.6, 3.8, 3.7, 3.5)
    )

    def __post_init__(self) -> None:
        for name in ("hfov_deg", "hand_scale", "palm_size_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be finite and > 0, got {value!r}")
        if len(self.theta_open_rad) != 5 or len(self.theta_closed_rad) != 5:
            raise ConfigError("theta_open_rad and theta_closed_rad need 5 values (thumb..little)")
        for lo, hi in zip(self.theta_open_rad, self.theta_closed_rad, strict=True):
            if not 0.0 <= lo < hi:
                raise ConfigError(f"need 0 <= theta_open < theta_closed per finger, got {lo}, {hi}")


@dataclass(frozen=True)
class PalmPose:
    """Unfiltered result of one frame.

    Attributes:
        p_cam_palm_m: (3,) palm centre in the camera frame [m].
        R_cam_palm: (3, 3) palm orientation (module docstring).
        openness: (5,) thumb..little in [0, 1].
        flexion_rad: (5,) summed joint flexion per finger [rad] (before normalisation).
    """

    p_cam_palm_m: Array
    R_cam_palm: Array
    openness: Array
    flexion_rad: Array

    def is_finite(self) -> bool:
        return bool(
            np.isfinite(self.p_cam_palm_m).all()
            and np.isfinite(self.R_cam_palm).all()
            and np.isfinite(self.openness).all()
        )


def _unit(v: Array) -> Array:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def palm_rotation(points: Array) -> Array:
    """R_cam_palm from landmark positions in camera-aligned axes (module docstring).

    Args:
        points: (21, 3) landmarks, any uniform scale (world metres or lifted pixels).

    Returns:
        (3, 3) rotation matrix with columns x_palm, y_palm, z_palm; NaN if degenerate.
    """
    wrist, index, little = points[WRIST], points[INDEX_MCP], points[LITTLE_MCP]
    x = _unit(0.5 * (index + little) - wrist)
    n = np.cross(little - wrist, index - wrist)
    z = _unit(n - np.dot(n, x) * x)
    y = np.cross(z, x)
    return np.stack([x, y, z], -1)


def palm_size(points: Array) -> float:
    """RMS distance of the rigid palm landmarks from their centroid, in `points`' units."""
    rigid = points[_PALM_RIGID]
    return float(np.sqrt(((rigid - rigid.mean(0)) ** 2).sum(1).mean()))


def joint_flexions(points: Array) -> tuple[Array, ...]:
    """Per finger (thumb..little), the angles [rad] between consecutive chain segments."""
    out = []
    for idx in _FINGER_IDX:
        seg = np.diff(points[idx], axis=0)
        seg = seg / np.linalg.norm(seg, axis=-1, keepdims=True)
        cos = np.clip(np.einsum("ij,ij->i", seg[:-1], seg[1:]), -1.0, 1.0)
        out.append(np.arccos(cos))
    return tuple(out)


def finger_flexion(points: Array) -> Array:
    """(5,) summed joint flexion per finger [rad], thumb..little, from (21, 3) points."""
    return np.array([float(a.sum()) for a in joint_flexions(points)])


def openness_from_flexion(flexion_rad: Array, config: PoseConfig) -> Array:
    """Normalise summed flexions (5,) [rad] to openness in [0, 1] (module docstring)."""
    lo = np.asarray(config.theta_open_rad)
    hi = np.asarray(config.theta_closed_rad)
    return np.clip((hi - flexion_rad) / (hi - lo), 0.0, 1.0)


def flexion_from_openness(openness: Array, config: PoseConfig) -> Array:
    """Inverse of `openness_from_flexion` on [0, 1]: summed flexion per finger [rad]."""
    lo = np.asarray(config.theta_open_rad)
    hi = np.asarray(config.theta_closed_rad)
    return hi - np.clip(openness, 0.0, 1.0) * (hi - lo)


def backproject_unit_depth(landmarks_image: Array, intrinsics: CameraIntrinsics) -> Array:
    """(21, 3) image shape b_i at unit wrist depth (module docstring), camera frame."""
    k = intrinsics
    u = landmarks_image[:, 0] * k.width_px
    v = landmarks_image[:, 1] * k.height_px
    depth = 1.0 + landmarks_image[:, 2] * k.width_px / k.fx_px
    return np.stack([depth * (u - k.cx_px) / k.fx_px, depth * (v - k.cy_px) / k.fy_px, depth], -1)


def estimate_palm_pose(
    detection: Detection, intrinsics: CameraIntrinsics, config: PoseConfig, mirrored: bool = False
) -> PalmPose:
    """Unfiltered palm pose and openness of one detection.

    Args:
        detection: landmarks of one hand.
        intrinsics: camera of the image the landmarks were found in.
        config: estimator parameters.
        mirrored: the image was flipped left-right (selfie view). The pose is computed in the
            mirrored geometry and reflected back into the physical camera frame, with
            S = diag(-1, 1, 1): p -> S p and R -> S R diag(1, 1, -1) (z_palm is a cross
            product of reflected vectors, so it flips once more).

    Returns:
        The palm pose; non-finite fields when the landmarks are degenerate.
    """
    b = backproject_unit_depth(detection.landmarks_image, intrinsics)
    world = detection.landmarks_world if detection.landmarks_world is not None else b
    with np.errstate(invalid="ignore", divide="ignore"):
        R = palm_rotation(world)
        flexion = finger_flexion(world)
        z_wrist = config.palm_size_m * config.hand_scale / palm_size(b)
        p = z_wrist * b[_PALM_CENTRE].mean(0)
    if mirrored:
        p = p * np.array([-1.0, 1.0, 1.0])
        R = (R * np.array([-1.0, 1.0, 1.0])[:, None]) * np.array([1.0, 1.0, -1.0])
    return PalmPose(p, R, openness_from_flexion(flexion, config), flexion)


def hand_scale_for_depth(pose: PalmPose, true_depth_m: float, config: PoseConfig) -> float:
    """The `hand_scale` that makes `pose` (estimated with `config`) sit at a known depth.

    Depth is proportional to `hand_scale`, so one frame of the hand at a measured distance
    from the camera (e.g. the palm 0.5 m from the lens) calibrates it.

    Args:
        pose: a pose estimated with `config`.
        true_depth_m: the palm centre's measured depth along the optical axis [m].
        config: the config `pose` was estimated with.
    """
    if not (math.isfinite(true_depth_m) and true_depth_m > 0):
        raise ContractError(f"true_depth_m must be finite and > 0, got {true_depth_m!r}")
    return config.hand_scale * true_depth_m / float(pose.p_cam_palm_m[2])
