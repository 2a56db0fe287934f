"""Where the kitchen task's scene stands in the robot's base frame: its placement.

The kitchen (robot/world.py) is written in the **scene frame**: x towards the table, y left,
z up, its origin where the iiwa's and the Panda's bases stand (at the table top's height,
0.22 m before the table's near edge). A robot stands the scene where it can reach it: the
scene frame's origin at `xyz_m` in the base frame, turned `yaw_rad` about the base's z axis,
so a point p of the scene lies at

    p_base = xyz_m + Rz(yaw_rad) p_scene

and every pose of the scene (the utensils' grasp poses, the place pose) turns with it. The
placement is the description's `[task]` table, or computed where the description gives none
(`robot.reach.task_placement`); the shipped robots stand the scene where it always was
(the identity), and then nothing is transformed at all: every number is the one it was.

Pure numpy, no PyBullet: the task (`robot.task`) judges outcomes in the scene frame with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import FormatError

Array = NDArray[np.float64]

#: How a placement was chosen: the description's `[task]` table, computed by the search
#: (`robot.reach`), or the shipped layout (no `[task]` and every pose reachable there).
SOURCES = ("description", "computed", "shipped")


@dataclass(frozen=True)
class Placement:
    """The scene frame in the robot base frame (module docstring).

    Attributes:
        xyz_m: the scene origin in the base frame [m].
        yaw_rad: the scene's turn about the base z axis [rad].
        source: how it was chosen (`SOURCES`).
    """

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rad: float = 0.0
    source: str = "shipped"

    @property
    def identity(self) -> bool:
        """The scene stands where it always did (nothing is transformed)."""
        return self.yaw_rad == 0.0 and not any(self.xyz_m)

    @property
    def R(self) -> Array:
        """Rz(yaw_rad): the scene's axes in the base frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def point(self, p_scene: Any) -> Array:
        """A scene point in the base frame (the identity: the same numbers)."""
        p = np.array(p_scene, dtype=np.float64)
        if self.identity:
            return p
        return np.asarray(np.array(self.xyz_m) + self.R @ p, dtype=np.float64)

    def rotation(self, R_scene: Array) -> Array:
        """A scene orientation in the base frame."""
        R = np.array(R_scene, dtype=np.float64)
        return R if self.identity else np.asarray(self.R @ R, dtype=np.float64)

    def pose(self, p_scene: Any, R_scene: Array) -> tuple[Array, Array]:
        """A scene pose (p, R) in the base frame."""
        return self.point(p_scene), self.rotation(R_scene)

    def to_scene(self, p_base: Array) -> Array:
        """A base-frame point in the scene frame (the inverse of `point`)."""
        p = np.asarray(p_base, dtype=np.float64)
        if self.identity:
            return p
        return np.asarray(self.R.T @ (p - np.array(self.xyz_m)), dtype=np.float64)

    def describe(self) -> str:
        """One line: where the scene stands and why."""
        x, y, z = self.xyz_m
        return (
            f"scene origin at ({x:+.3f}, {y:+.3f}, {z:+.3f}) m, yaw {self.yaw_rad:+.3f} rad "
            f"({self.source})"
        )

    def to_dict(self) -> dict[str, Any]:
        """What a recording keeps (a replay stands the scene where the run did)."""
        return {"xyz_m": list(self.xyz_m), "yaw_rad": self.yaw_rad, "source": self.source}

    @classmethod
    def from_dict(cls, d: Any) -> Placement:
        """From `to_dict`'s form (a recorded task's `placement`).

        Raises:
            FormatError: not a placement (one line).
        """
        try:
            xyz = [float(v) for v in d["xyz_m"]]
            yaw = float(d["yaw_rad"])
            source = str(d.get("source", "description"))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise FormatError(f"task placement: not a recorded placement: {d!r}") from None
        if len(xyz) != 3 or not all(math.isfinite(v) for v in (*xyz, yaw)):
            raise FormatError(f"task placement: not a recorded placement: {d!r}")
        if source not in SOURCES:
            source = "description"
        return cls((xyz[0], xyz[1], xyz[2]), yaw, source)


#: The shipped layout: the scene frame is the base frame.
SHIPPED = Placement()
