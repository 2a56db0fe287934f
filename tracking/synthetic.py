"""The synthetic operator hand: a kinematic hand model that produces MediaPipe-format
landmarks, with ground truth, for a given camera.

Model (palm frame of `pose.py`: x towards the fingers, z out of the palm, origin at the palm
centre; a right hand, a left hand is its mirror image):
    * fixed wrist, thumb CMC and four finger MCPs (an adult hand, palm length ~9 cm), the
      whole hand scaled so that its palm size is the estimator's `palm_size_m * hand_scale`;
    * each finger a planar chain of three phalanges from its MCP, straight along the
      wrist -> MCP direction when unflexed, curling towards +z (the palm side); the thumb a
      chain of metacarpal + two phalanges from its CMC, curling across the palm;
    * a finger of openness o has the summed flexion theta(o) = `pose.flexion_from_openness`
      of the estimator's config, split over its joints in fixed ratios (fingers: MCP 40 %,
      PIP 35 %, DIP 25 %; thumb: MCP 50 %, IP 50 %). Openness is thus *defined* as the
      normalised summed flexion, the same quantity the estimator measures, and a round trip
      returns it exactly in the absence of noise.

Landmarks for a palm pose (p_cam_palm, R_cam_palm) and a pinhole camera:
    world (hand-centred, camera-aligned, m):  w_i = R_cam_palm q_i - mean_j(R_cam_palm q_j)
    camera points:                            P_i = p_cam_palm + R_cam_palm q_i
    image (normalised like MediaPipe):        x_i = u_i / W, y_i = v_i / H,
                                              z_i = fx (Z_i - Z_wrist) / (Z_wrist W),
with (u_i, v_i) the pinhole projection of P_i. Optional Gaussian noise (pixels on the image
landmarks, metres on the world ones) mimics a detector.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dsteleop.arbitration.se3 import HandState, so3_exp
from dsteleop.errors import ConfigError
from dsteleop.tracking.landmarks import FINGER_CHAINS, N_LANDMARKS, PALM_CENTRE, WRIST
from dsteleop.tracking.pose import (
    CameraIntrinsics,
    PoseConfig,
    flexion_from_openness,
    palm_rotation,
    palm_size,
)
from dsteleop.tracking.types import Array, Detection, Frame, Handedness

#: A scripted or modelled operator: time [s] -> (palm pose in the camera frame as a
#: HandState whose openness is ignored, openness (5,) thumb..little), or None when the hand
#: is out of view.
Trajectory = Callable[[float], tuple[HandState, Array] | None]


@dataclass(frozen=True)
class HandModel:
    """Geometry of the kinematic hand (right hand, metres, see module docstring).

    Attributes:
        wrist_to_mcp_m: (4, 2) MCP positions (x, y) of index..little relative to the wrist
            in the palm plane, y towards the thumb [m].
        thumb_cmc_m: (x, y, z) of the thumb CMC relative to the wrist [m].
        phalanges_m: (4, 3) proximal, middle, distal lengths of index..little [m].
        thumb_m: thumb metacarpal, proximal and distal lengths [m].
        thumb_direction: direction of the unflexed thumb metacarpal (palm axes, unnormalised).
        thumb_curl: direction the thumb curls towards (palm axes, unnormalised).
        finger_joint_split: share of a finger's flexion at MCP, PIP, DIP.
        thumb_joint_split: share of the thumb's flexion at MCP and IP.
    """

    wrist_to_mcp_m: tuple[tuple[float, float], ...] = (
        (0.088, 0.030),
        (0.092, 0.008),
        (0.087, -0.013),
        (0.078, -0.032),
    )
    thumb_cmc_m: tuple[float, float, float] = (0.025, 0.022, 0.008)
    phalanges_m: tuple[tuple[float, float, float], ...] = (
        (0.040, 0.025, 0.020),
        (0.045, 0.028, 0.020),
        (0.042, 0.026, 0.020),
        (0.032, 0.020, 0.018),
    )
    thumb_m: tuple[float, float, float] = (0.035, 0.032, 0.025)
    thumb_direction: tuple[float, float, float] = (0.6, 0.7, 0.25)
    thumb_curl: tuple[float, float, float] = (0.2, -1.0, 1.0)
    finger_joint_split: tuple[float, float, float] = (0.40, 0.35, 0.25)
    thumb_joint_split: tuple[float, float] = (0.5, 0.5)

    def landmarks_palm(
        self, openness: Array, config: PoseConfig, handedness: Handedness = "Right"
    ) -> Array:
        """(21, 3) landmarks [m] in the palm frame for openness (5,) thumb..little."""
        theta = flexion_from_openness(np.asarray(openness, dtype=np.float64), config)
        pts = np.zeros((N_LANDMARKS, 3))
        pts[WRIST] = 0.0
        z = np.array([0.0, 0.0, 1.0])
        # Fingers: chain (wrist, MCP, PIP, DIP, tip), bones curling from d0 towards +z.
        for f, chain in enumerate(FINGER_CHAINS[1:]):
            base = np.array([*self.wrist_to_mcp_m[f], 0.0])
            pts[chain[1]] = base
            d0 = base / np.linalg.norm(base)
            phi = 0.0
            for j, (a, b) in enumerate(itertools.pairwise(chain[1:])):
                phi += self.finger_joint_split[j] * theta[f + 1]
                bone = math.cos(phi) * d0 + math.sin(phi) * z
                pts[b] = pts[a] + self.phalanges_m[f][j] * bone
        # Thumb: chain (CMC, MCP, IP, tip), metacarpal along t0, phalanges curling to `curl`.
        cmc, mcp, ip, tip = FINGER_CHAINS[0]
        t0 = np.asarray(self.thumb_direction, dtype=np.float64)
        t0 /= np.linalg.norm(t0)
        curl = np.asarray(self.thumb_curl, dtype=np.float64)
        curl -= np.dot(curl, t0) * t0
        curl /= np.linalg.norm(curl)
        pts[cmc] = self.thumb_cmc_m
        pts[mcp] = pts[cmc] + self.thumb_m[0] * t0
        phi = 0.0
        for j, (a, b) in enumerate(((mcp, ip), (ip, tip))):
            phi += self.thumb_joint_split[j] * theta[0]
            pts[b] = pts[a] + self.thumb_m[j + 1] * (math.cos(phi) * t0 + math.sin(phi) * curl)
        # Express in the estimator's palm frame (origin at the palm centre), so that the
        # estimator returns the commanded pose exactly.
        R0 = palm_rotation(pts)
        q = (pts - pts[np.asarray(PALM_CENTRE)].mean(0)) @ R0
        # Size the hand to the estimator's reference palm (times its hand scale).
        q *= config.palm_size_m * config.hand_scale / palm_size(q)
        if handedness == "Left":
            # The mirror image y -> -y, expressed in the estimator's frame of a left hand
            # (its z_palm leaves the back of the hand): (x, y, z) -> (x, y, -z).
            q = q * np.array([1.0, 1.0, -1.0])
        return q


@dataclass(frozen=True)
class LandmarkNoise:
    """Gaussian detector noise.

    Attributes:
        image_px: standard deviation on image landmarks x and y [px] (z gets the same
            amount on its own scale).
        world_m: standard deviation on each world landmark coordinate [m].
    """

    image_px: float = 0.0
    world_m: float = 0.0


def synthesize_detection(
    p_cam_palm_m: Array,
    R_cam_palm: Array,
    openness: Array,
    camera: CameraIntrinsics,
    *,
    model: HandModel | None = None,
    config: PoseConfig | None = None,
    handedness: Handedness = "Right",
    noise: LandmarkNoise | None = None,
    rng: np.random.Generator | None = None,
    score: float = 1.0,
) -> Detection:
    """MediaPipe-format landmarks of the model hand at a pose (module docstring).

    Args:
        p_cam_palm_m: (3,) palm centre in the camera frame [m], z > 0.
        R_cam_palm: (3, 3) palm orientation in the camera frame.
        openness: (5,) thumb..little in [0, 1].
        camera: intrinsics of the image.
        model: hand geometry (default `HandModel()`).
        config: estimator config whose openness definition is used (default `PoseConfig()`).
        handedness: anatomical hand.
        noise: detector noise (None: exact landmarks).
        rng: random generator for the noise.
        score: reported confidence.

    Returns:
        The detection, with world landmarks (unmirrored image).
    """
    model = model or HandModel()
    config = config or PoseConfig()
    q = model.landmarks_palm(openness, config, handedness)
    offsets = q @ np.asarray(R_cam_palm, dtype=np.float64).T
    P = np.asarray(p_cam_palm_m, dtype=np.float64) + offsets
    uv = camera.project(P)
    z_w = P[WRIST, 2]
    img = np.empty((N_LANDMARKS, 3))
    img[:, 0] = uv[:, 0] / camera.width_px
    img[:, 1] = uv[:, 1] / camera.height_px
    img[:, 2] = camera.fx_px * (P[:, 2] - z_w) / (z_w * camera.width_px)
    world = offsets - offsets.mean(0)
    if noise is not None and (noise.image_px > 0 or noise.world_m > 0):
        rng = rng or np.random.default_rng()
        scale = np.array([camera.width_px, camera.height_px, camera.width_px], dtype=np.float64)
        img = img + rng.normal(0.0, noise.image_px, img.shape) / scale
        world = world + rng.normal(0.0, noise.world_m, world.shape)
    return Detection(img, world, handedness, score)


def palm_facing_camera() -> Array:
    """R_cam_palm of a hand held up in front of the camera, palm towards it, fingers up."""
    return np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def scripted_trajectory(
    center_cam_m: tuple[float, float, float] = (0.0, 0.0, 0.5), period_s: float = 8.0
) -> Trajectory:
    """A smooth, repeating reach-grasp-turn motion of a right hand in front of the camera.

    The palm faces the camera at `center_cam_m`; over one period it sweeps +-8 cm sideways,
    +-5 cm up and down and 6 cm towards the camera, turns up to +-0.5 rad about each axis,
    and closes the fingers to a grasp and opens them again. Stands in for the stochastic
    operator model (`app/operator/open_loop.py`) where that is not available.

    Args:
        center_cam_m: centre of the motion in the camera frame [m].
        period_s: duration of one cycle [s].
    """
    c = np.asarray(center_cam_m, dtype=np.float64)
    R0 = palm_facing_camera()

    def trajectory(t_s: float) -> tuple[HandState, Array]:
        ph = 2.0 * math.pi * t_s / period_s
        p = c + np.array([0.08 * math.sin(ph), 0.05 * math.sin(2 * ph), -0.03 * (1 - math.cos(ph))])
        w = np.array([0.3 * math.sin(ph), 0.5 * math.sin(ph + 1.0), 0.4 * math.sin(2 * ph)])
        R = so3_exp(w) @ R0
        grasp = 0.5 * (1.0 - math.cos(ph))  # 0 open .. 1 closed
        openness = np.clip(1.0 - grasp * np.array([0.6, 0.9, 0.95, 0.95, 0.9]), 0.0, 1.0)
        return HandState(p, R, openness), openness

    return trajectory


class SyntheticSource:
    """A hand source whose frames carry landmarks of the kinematic hand (no pixels).

    Frames have `detections` set and `image` None: the tracker feeds them straight to the
    pose estimator. Read as fast as possible, `t_capture_s` is the trajectory time
    seq / fps; with `realtime=True`, `read()` paces frames at `fps` and stamps them with
    `time.monotonic()`.

    Args:
        trajectory: the operator (see `Trajectory`).
        fps: frame rate [Hz].
        duration_s: length [s] (None: endless).
        camera: intrinsics of the virtual camera (default 640x480, 60 deg).
        handedness: anatomical hand.
        noise: detector noise on the landmarks.
        seed: seed of the noise.
        realtime: pace at `fps` on the monotonic clock.
        model: hand geometry.
        config: estimator config whose openness definition is used.
    """

    has_pixels = False  # no detector to load for it (`TrackingStream.open`)

    def __init__(
        self,
        trajectory: Trajectory,
        *,
        fps: float = 30.0,
        duration_s: float | None = None,
        camera: CameraIntrinsics | None = None,
        handedness: Handedness = "Right",
        noise: LandmarkNoise | None = None,
        seed: int = 0,
        realtime: bool = False,
        model: HandModel | None = None,
        config: PoseConfig | None = None,
    ) -> None:
        if not (math.isfinite(fps) and fps > 0):
            raise ConfigError(f"fps must be > 0, got {fps!r}")
        self.trajectory = trajectory
        self.fps = fps
        self.duration_s = duration_s
        self.camera = camera or CameraIntrinsics.from_hfov(640, 480, 60.0)
        self.handedness: Handedness = handedness
        self.noise = noise
        self.realtime = realtime
        self.model = model or HandModel()
        self.config = config or PoseConfig()
        self._seed = seed
        self._rng = np.random.default_rng(seed)
        self._seq = 0
        self._t0 = 0.0
        self.truth: dict[int, tuple[HandState, Array] | None] = {}
        self.keep_truth = False

    def describe(self) -> str:
        return (
            f"synthetic operator ({self.fps:g} fps, {self.camera.width_px}x{self.camera.height_px})"
        )

    def open(self) -> None:
        self._seq = 0
        self._rng = np.random.default_rng(self._seed)
        self._t0 = time.monotonic()

    def close(self) -> None:
        return None

    def read(self) -> Frame | None:
        """The next frame, or None when `duration_s` has passed."""
        t = self._seq / self.fps
        if self.duration_s is not None and t > self.duration_s + 1e-9:
            return None
        if self.realtime:
            delay = self._t0 + t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        target = self.trajectory(t)
        if self.keep_truth:
            self.truth[self._seq] = target
        detections: tuple[Detection, ...] = ()
        if target is not None:
            pose, openness = target
            detections = (
                synthesize_detection(
                    pose.position,
                    pose.rotation,
                    openness,
                    self.camera,
                    model=self.model,
                    config=self.config,
                    handedness=self.handedness,
                    noise=self.noise,
                    rng=self._rng,
                ),
            )
        frame = Frame(
            seq=self._seq,
            t_capture_s=time.monotonic() if self.realtime else t,
            width_px=self.camera.width_px,
            height_px=self.camera.height_px,
            detections=detections,
        )
        self._seq += 1
        return frame
