"""Camera frame -> robot workspace: the hand as `X_human` and `g_human`.

The camera-to-robot axes are defined here and nowhere else. The camera frame is OpenCV's
(x right in the image, y down, z along the optical axis, away from the camera); the robot
base frame is x forward, y left, z up (docs/CONVENTIONS.md).

    mirror=True  (default; a webcam in front of the operator, looking at them, like a mirror):
        the operator's forward is towards the camera, their left is the image's right:
        x_base = -z_cam,  y_base = +x_cam,  z_base = -y_cam.
    mirror=False (a camera behind or above the operator, looking where they look):
        x_base = +z_cam,  y_base = -x_cam,  z_base = -y_cam.

Both are proper rotations R_base_cam, so orientations map by R_base_cam R_cam_palm. (Whether
the *image* was flipped for a selfie display is a different matter, undone by the tracker's
`mirrored` flag before poses reach this module.)

Mapping, relative to an anchor (hand pose h0 in the camera frame, robot pose r0):

    p_base   = clip(p_r0 + s * (R_base_cam (p_cam - p_h0)),  workspace_min, workspace_max)
    R_base   = (R_base_cam R_cam_palm R_h0^T R_base_cam^T) R_r0

with s the per-axis scale (robot metres per hand metre, in base axes). The hand's rotation
since the anchor, expressed in the base frame, is applied to the robot's anchor orientation,
so turning the hand about the camera's vertical axis yaws the robot about its z.
Fingers: each robot finger's openness is the mean of the human fingers its robot description
names (`MappingConfig.robot_fingers`). The default is the iiwa's hand (`ROBOT_FINGERS`): the
robot's thumb, index, middle come from the same human fingers, its ring from the mean of the
human ring and little fingers. A gripper of one openness (the Panda) takes the pinch, the mean
of thumb and index (docs/robots.md).

`calibrate(sample)` re-centres: the current hand pose becomes the anchor and the robot pose
it maps to *now* stays where it is (no jump); the first mapping (or `calibrate(sample,
to_neutral=True)`) anchors the hand on the configured neutral robot pose instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dsteleop.arbitration.se3 import HandState, so3_exp
from dsteleop.errors import ConfigError, ContractError
from dsteleop.tracking.landmarks import FINGER_NAMES
from dsteleop.tracking.types import Array, HandSample

#: Rows: base axes in camera coordinates (module docstring).
R_BASE_CAM_MIRROR = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_BASE_CAM_BEHIND = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

#: Robot finger -> the human fingers (by name) whose openness is averaged.
ROBOT_FINGERS: dict[str, tuple[str, ...]] = {
    "thumb": ("thumb",),
    "index": ("index",),
    "middle": ("middle",),
    "ring": ("ring", "little"),
}
#: A robot's fingers and the human fingers each follows, in the robot's finger order.
RobotFingers = tuple[tuple[str, tuple[str, ...]], ...]
DEFAULT_ROBOT_FINGERS: RobotFingers = tuple(ROBOT_FINGERS.items())


def finger_mix(robot_fingers: RobotFingers = DEFAULT_ROBOT_FINGERS) -> Array:
    """(F, 5) weights: row f averages the human fingers robot finger f follows."""
    return np.array(
        [[1.0 / len(src) if h in src else 0.0 for h in FINGER_NAMES] for _, src in robot_fingers]
    )


_FINGER_MIX = finger_mix()


def robot_openness(openness: Array, mix: Array = _FINGER_MIX) -> Array:
    """Human openness (..., 5) thumb..little -> robot (..., F) by `mix` (`finger_mix`;
    default the iiwa hand's thumb, index, middle, ring)."""
    return np.asarray(openness, dtype=np.float64) @ mix.T


def human_openness(robot_openness: Array, mix: Array = _FINGER_MIX) -> Array:
    """A human hand (5,) thumb..little that `robot_openness` (F,) maps back from: each human
    finger takes the mean of the robot fingers that follow it, one no robot finger follows
    the mean of all (the iiwa hand: the little finger follows the ring; a gripper: all five
    fingers as open as the gripper). `robot_openness(human_openness(g, mix), mix) == g`."""
    g = np.asarray(robot_openness, dtype=np.float64)
    used = mix > 0.0  # (F, 5)
    counts = used.sum(0)
    per_human = (used * g[:, None]).sum(0) / np.maximum(counts, 1)
    return np.asarray(np.where(counts > 0, per_human, g.mean()), dtype=np.float64)


def _vec3(name: str, value: tuple[float, float, float]) -> Array:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise ConfigError(f"{name} must be 3 finite numbers, got {value!r}")
    return a


@dataclass(frozen=True)
class MappingConfig:
    """Workspace mapping settings (module docstring).

    Attributes:
        neutral_position_m: robot palm position the neutral hand maps to [m], base frame.
        neutral_rotvec_rad: robot palm orientation the neutral hand maps to, as a rotation
            vector [rad] in the base frame (default: the palm frame aligned with the base).
        scale: robot metres per hand metre along base x, y, z.
        mirror: camera in front of the operator looking at them (True) or looking where
            they look (False).
        workspace_min_m: lower corner of the reachable box [m], base frame.
        workspace_max_m: upper corner [m].
        robot_fingers: the robot's fingers in order, each with the human fingers whose
            mean openness it follows (from the robot's description; default the iiwa hand).
    """

    neutral_position_m: tuple[float, float, float] = (0.45, 0.0, 0.30)
    neutral_rotvec_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: tuple[float, float, float] = (1.5, 1.5, 1.5)
    mirror: bool = True
    workspace_min_m: tuple[float, float, float] = (0.15, -0.45, 0.02)
    workspace_max_m: tuple[float, float, float] = (0.80, 0.45, 0.70)
    robot_fingers: RobotFingers = DEFAULT_ROBOT_FINGERS

    def __post_init__(self) -> None:
        # read back from JSON as nested lists: the same table as tuples
        fingers = tuple((str(f), tuple(str(h) for h in src)) for f, src in self.robot_fingers)
        object.__setattr__(self, "robot_fingers", fingers)
        for f, src in fingers:
            bad = [h for h in src if h not in FINGER_NAMES]
            if not src or bad:
                raise ConfigError(f"robot finger {f!r} must follow human fingers of {FINGER_NAMES}")
        lo = _vec3("workspace_min_m", self.workspace_min_m)
        hi = _vec3("workspace_max_m", self.workspace_max_m)
        if not (lo < hi).all():
            raise ConfigError("workspace_min_m must be below workspace_max_m on every axis")
        p0 = _vec3("neutral_position_m", self.neutral_position_m)
        if not ((lo <= p0) & (p0 <= hi)).all():
            raise ConfigError("neutral_position_m must lie inside the workspace")
        s = _vec3("scale", self.scale)
        if not (s > 0).all():
            raise ConfigError(f"scale must be > 0 on every axis, got {self.scale!r}")
        r0 = _vec3("neutral_rotvec_rad", self.neutral_rotvec_rad)
        if float(np.linalg.norm(r0)) > math.pi + 1e-9:
            raise ConfigError("neutral_rotvec_rad must have a norm <= pi")

    @property
    def R_base_cam(self) -> Array:
        """Rotation from camera to robot base axes (module docstring)."""
        return R_BASE_CAM_MIRROR if self.mirror else R_BASE_CAM_BEHIND


class WorkspaceMapping:
    """Maps tracked samples to `HandState`s in the robot base frame (module docstring).

    Stateful only through its anchor; not thread-safe (one owner, the control loop).
    """

    def __init__(self, config: MappingConfig | None = None) -> None:
        self.config = config or MappingConfig()
        self.mix = finger_mix(self.config.robot_fingers)
        """(F, 5) human -> robot finger weights of this mapping (`finger_mix`)."""
        self._anchor_cam: tuple[Array, Array] | None = None
        self._anchor_robot: tuple[Array, Array] | None = None

    @property
    def calibrated(self) -> bool:
        """True once an anchor is set."""
        return self._anchor_cam is not None

    def neutral(self) -> tuple[Array, Array]:
        """The neutral robot palm pose (position [m], rotation) from the config."""
        c = self.config
        return np.array(c.neutral_position_m), so3_exp(np.array(c.neutral_rotvec_rad))

    @staticmethod
    def _pose(sample: HandSample) -> tuple[Array, Array]:
        if not sample.has_pose:
            raise ContractError("sample has no hand pose yet (no hand seen)")
        return sample.p_cam_palm_m, sample.R_cam_palm

    def calibrate(self, sample: HandSample, to_neutral: bool = False) -> None:
        """Re-centre on the hand's current pose.

        Args:
            sample: the current sample (its filtered pose becomes the hand anchor).
            to_neutral: map the current hand to the configured neutral robot pose (a jump
                if the robot is elsewhere) instead of to where it maps now (no jump).
        """
        if to_neutral or self._anchor_cam is None:
            robot = self.neutral()
        else:
            state = self.map(sample)
            robot = (state.position, state.rotation)
        self._anchor_cam = self._pose(sample)
        self._anchor_robot = robot

    def map(self, sample: HandSample) -> HandState:
        """The hand as a `HandState` in the robot base frame, with the robot's fingers.

        The first call anchors the current hand on the neutral robot pose.

        Raises:
            ContractError: the sample has no pose (no hand seen yet).
        """
        p_cam, R_cam = self._pose(sample)
        if self._anchor_cam is None or self._anchor_robot is None:
            self.calibrate(sample, to_neutral=True)
        assert self._anchor_cam is not None and self._anchor_robot is not None
        (p_h0, R_h0), (p_r0, R_r0) = self._anchor_cam, self._anchor_robot
        c = self.config
        Rbc = c.R_base_cam
        p = np.clip(
            p_r0 + np.array(c.scale) * (Rbc @ (p_cam - p_h0)),
            np.array(c.workspace_min_m),
            np.array(c.workspace_max_m),
        )
        R = Rbc @ R_cam @ R_h0.T @ Rbc.T @ R_r0
        return HandState(p, R, robot_openness(sample.openness, self.mix))

    def to_camera(self, state: HandState) -> tuple[Array, Array]:
        """Inverse of `map` for the pose (ignoring the workspace clip): the camera-frame palm
        pose (position [m], rotation) that maps to `state`. For operator models that plan
        in the robot frame and feed the synthetic hand.

        Raises:
            ContractError: before the mapping has an anchor.
        """
        if self._anchor_cam is None or self._anchor_robot is None:
            raise ContractError("mapping has no anchor yet: calibrate first")
        (p_h0, R_h0), (p_r0, R_r0) = self._anchor_cam, self._anchor_robot
        Rbc = self.config.R_base_cam
        p_cam = p_h0 + Rbc.T @ ((state.position - p_r0) / np.array(self.config.scale))
        R_cam = Rbc.T @ state.rotation @ R_r0.T @ Rbc @ R_h0
        return p_cam, R_cam

    def anchor_at(self, p_cam_m: Array, R_cam: Array, robot: HandState | None = None) -> None:
        """Set the anchor directly: the camera pose (p_cam_m, R_cam) maps to `robot`'s pose
        (default: the neutral pose)."""
        self._anchor_cam = (
            np.asarray(p_cam_m, dtype=np.float64),
            np.asarray(R_cam, dtype=np.float64),
        )
        self._anchor_robot = self.neutral() if robot is None else (robot.position, robot.rotation)
