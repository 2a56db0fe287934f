"""The robot's perception error: how far the pose it knows of an object is from the true one.

The robot sees the objects through its own RGB-D camera (`ROBOT_CAMERA_M`: its optical
centre 1 m above the robot's base, looking at `ROBOT_CAMERA_TARGET_M` on the table between
the holder and the bin; robot/world.py draws the rest of the kitchen). A pose
estimated from one view is least certain along the ray from the camera to the object (its
depth) and more certain across it, so the error of an object's known position is

    dp = sigma_lateral * (n1 e1 + n2 e2) + sigma_depth * n3 u,    n ~ N(0, I_3)

with u the unit ray from the camera to the object and e1, e2 completing it to an orthonormal
frame: covariance Sigma = sigma_lateral^2 I + (sigma_depth^2 - sigma_lateral^2) u u^T. Its
orientation error is a rotation vector ~ N(0, sigma_rot^2 I) about the base axes,
R_known = exp(dr) R_true. The robot knows these statistics: the belief over the candidates
(`arbitration.belief`) takes each candidate's per-axis standard deviation in the base frame,
the square root of Sigma's diagonal, sqrt(sigma_lateral^2 + (sigma_depth^2 - sigma_lateral^2)
u_i^2) (the belief treats the axes as independent, so the correlation between them is left
out), the rotation's sigma_rot on each rotation axis, and 0 on the fingers (the finger goal
is the task's schedule, not perceived).

An isotropic error (`PerceptionError.isotropic`, the same sd on every axis, no camera) is
the goal noise of a told goal (`--goal-noise`): it draws exactly as the task always drew
(`rng.normal(0, sigma, 3)` for the position, then for the rotation), so a seed gives the
same noisy goals it gave before this model.

The values (fixed from the literature before any mode was measured with them,
docs/robot.md "The robot's perception" lists the sources):

    depth_sigma_m = 0.02      a consumer RGB-D camera's random depth error grows with the
                              square of the distance, a few mm at 1 m for a flat textured
                              target (Kinect v1: Khoshelham & Oude Elberink 2012; Intel
                              RealSense D4xx: RMS = Z^2 * subpixel / (f * baseline), about
                              3-4 mm at 1 m for a D435, absolute accuracy <= 2 % at 2 m,
                              Grunnet-Jepsen et al.); an object's pose from one view is much
                              worse than a flat wall, and worst along the ray (Xiang et al.
                              2018, PoseCNN: the object's distance is the hardest part of the
                              translation; the YCB-Video benchmark counts a pose as right
                              within 2 cm, ADD(-S)), the more so for a utensil's 24 mm grip
                              seen edge-on (few depth pixels, mixed pixels at its edges). 2 cm
                              is the goal noise the study's world already takes from the same
                              sources (docs/operator.md), here along the ray only.
    lateral_sigma_m = 0.005   across the ray a pixel at 1 m is about 2 mm (640 px over a
                              60-70 deg field of view), the object's image centre is off by a
                              pixel or two, and a camera-to-robot (hand-eye) calibration
                              leaves a few millimetres in every axis (Tsai & Lenz 1989).
    rotation_sigma_rad = 0.05 about 3 deg, the order of single-view pose estimators' rotation
                              errors on household objects (Xiang et al. 2018), and the task's
                              own goal rotation noise (`TaskConfig.goal_noise_rot_rad`).

At the kitchen's utensils (0.9-1.0 m from the camera, the rays about (0.6, 0.3, -0.73)) this
is about 12-14, 8 and 14-16 mm along base x, y and z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import so3_exp
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]

#: The robot's camera (module docstring): its optical centre in the base frame [m], and the
#: point it looks at. Each object's depth is measured along the ray from here to it.
ROBOT_CAMERA_M = (0.0, 0.0, 1.0)
ROBOT_CAMERA_TARGET_M = (0.58, 0.0, 0.0)


@dataclass(frozen=True)
class PerceptionError:
    """The robot's perception error (module docstring). Validated at construction.

    Attributes:
        lateral_sigma_m: sd of an object's position across the camera's ray [m].
        depth_sigma_m: sd along the ray [m].
        rotation_sigma_rad: sd of its orientation, per base axis [rad].
        camera_m: the camera's optical centre in the base frame [m]; None: isotropic (no
            camera: `depth_sigma_m` must equal `lateral_sigma_m`).
    """

    lateral_sigma_m: float = 0.005
    depth_sigma_m: float = 0.02
    rotation_sigma_rad: float = 0.05
    camera_m: tuple[float, float, float] | None = ROBOT_CAMERA_M

    def __post_init__(self) -> None:
        for name in ("lateral_sigma_m", "depth_sigma_m", "rotation_sigma_rad"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (
                isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
            ):
                raise ConfigError(f"perception: {name} must be a number >= 0, got {v!r}")
        if self.camera_m is None and self.depth_sigma_m != self.lateral_sigma_m:
            raise ConfigError("perception: without a camera the error is isotropic")

    @classmethod
    def isotropic(cls, sigma_m: float, sigma_rad: float) -> PerceptionError:
        """The same sd on every position axis (a told goal's `--goal-noise`)."""
        return cls(sigma_m, sigma_m, sigma_rad, None)

    @property
    def kind(self) -> str:
        """ "camera" or "isotropic"."""
        return "isotropic" if self.camera_m is None else "camera"

    def ray(self, p_m: Array) -> Array:
        """(3,) the unit ray from the camera to the position `p_m` (an isotropic model: x)."""
        if self.camera_m is None:
            return np.array([1.0, 0.0, 0.0])
        d = np.asarray(p_m, dtype=np.float64) - np.asarray(self.camera_m)
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            raise ConfigError(f"perception: an object at the camera ({list(self.camera_m)})")
        return d / n

    def position_sigma(self, p_m: Array) -> Array:
        """(3,) the sd of the known position along each base axis, at `p_m` [m]."""
        lat, dep = self.lateral_sigma_m, self.depth_sigma_m
        u = self.ray(p_m)
        return np.sqrt(lat * lat + (dep * dep - lat * lat) * u * u)

    def sigma(self, p_m: Array, n_fingers: int) -> Array:
        """(6 + F,) the per-dimension sd the belief takes for an object at `p_m`: the
        position's per-axis sd, the rotation's on each rotation axis, 0 on the fingers."""
        return np.concatenate(
            [
                self.position_sigma(p_m),
                np.full(3, float(self.rotation_sigma_rad)),
                np.zeros(n_fingers),
            ]
        )

    def sample(self, p_m: Array, R: Array, rng: np.random.Generator) -> tuple[Array, Array]:
        """The pose the robot knows of an object at (p_m, R): one draw of the error."""
        lat, dep, sr = self.lateral_sigma_m, self.depth_sigma_m, self.rotation_sigma_rad
        p = np.asarray(p_m, dtype=np.float64)
        if self.camera_m is None:
            dp = rng.normal(0.0, lat, 3) if lat > 0 else np.zeros(3)
        else:
            u = self.ray(p)
            e1 = np.cross(u, [0.0, 0.0, 1.0])
            if np.linalg.norm(e1) < 1e-6:  # looking straight down or up
                e1 = np.cross(u, [1.0, 0.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(u, e1)
            n = rng.normal(0.0, 1.0, 3)
            dp = lat * (n[0] * e1 + n[1] * e2) + dep * n[2] * u
        dr = rng.normal(0.0, sr, 3) if sr > 0 else np.zeros(3)
        return p + dp, so3_exp(dr) @ np.asarray(R, dtype=np.float64)

    def describe(self) -> str:
        """One line for a status or a log."""
        if self.camera_m is None:
            return (
                f"goal noise {1000 * self.lateral_sigma_m:g} mm per axis, "
                f"{self.rotation_sigma_rad:g} rad"
            )
        cam = ", ".join(f"{v:g}" for v in self.camera_m)
        return (
            f"robot camera at ({cam}) m: depth {1000 * self.depth_sigma_m:g} mm, lateral "
            f"{1000 * self.lateral_sigma_m:g} mm, rotation {self.rotation_sigma_rad:g} rad"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "lateral_sigma_m": self.lateral_sigma_m,
            "depth_sigma_m": self.depth_sigma_m,
            "rotation_sigma_rad": self.rotation_sigma_rad,
            "camera_m": None if self.camera_m is None else list(self.camera_m),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> PerceptionError:
        """From `to_dict`'s form (a recorded task's)."""
        try:
            cam = d.get("camera_m")
            xyz = None if cam is None else [float(c) for c in cam]  # type: ignore[attr-defined]
            return cls(
                float(d["lateral_sigma_m"]),  # type: ignore[arg-type]
                float(d["depth_sigma_m"]),  # type: ignore[arg-type]
                float(d["rotation_sigma_rad"]),  # type: ignore[arg-type]
                None if xyz is None else (xyz[0], xyz[1], xyz[2]),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f"perception: not a recorded perception model: {d!r}") from exc
