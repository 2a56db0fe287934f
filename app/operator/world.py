"""The operator's world: the impairments under which a simulated person teleoperates.

The paper's own study names three impairments that make assistance worth having (Section
IV-C): noise on the robot's goal, an induced teleoperation delay, and a single camera view in
which depth is hard to judge. Each is one mechanism with its own parameters here; the study,
the sweep (`dsteleop sim --sweep`) and the demo person read the same object. docs/operator.md
gives each parameter's source; they are fixed from the literature, never tuned to a result
(written down on 2026-12-02 before any S vs DS comparison of this world was run).

The camera (`view_axis`): in the planar study and in the demo's kitchen alike, the operator
sees the robot through one camera whose optical axis lies along the robot base's x axis
(the demo's virtual camera faces the operator with the mirror mapping, its optical axis
being base -x; the study's camera stands in front of the planar workspace looking back along
-x, the paper's single Kinect view of Fig. 7), so depth is base x and the screen shows y, z.

    goal noise     the robot's goal = the true goal + N(0, goal_sigma_m^2) per position axis
    delay          the operator's command reaches the robot `delay_s` late, and the robot's
                   image reaches the operator `delay_s` late (a round trip of 2 delay_s on
                   top of the person's own visual feedback delay)
    single view    the operator perceives the robot's position through one camera: the
                   perception error along the camera's viewing axis (`view_axis`, a unit
                   vector in the robot base frame) has sd `depth_sigma_m`, across it
                   `lateral_sigma_m`
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState
from dsteleop.errors import ConfigError


@dataclass(frozen=True)
class Impairments:
    """The world a simulated operator works in (module docstring). Validated at construction.

    Attributes:
        goal_sigma_m: sd of the robot's goal position per axis [m].
        delay_s: one-way teleoperation delay [s]: command to robot, and image to operator.
        depth_sigma_m: sd of the perceived robot position along the camera's viewing axis [m].
        lateral_sigma_m: sd of the perceived robot position across the viewing axis [m].
        view_axis: the camera's viewing direction in the robot base frame (unit 3-vector).
    """

    goal_sigma_m: float = 0.02
    delay_s: float = 0.2
    depth_sigma_m: float = 0.015
    lateral_sigma_m: float = 0.003
    view_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("goal_sigma_m", "delay_s", "depth_sigma_m", "lateral_sigma_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (
                isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
            ):
                raise ConfigError(f"{name} must be a number >= 0, got {v!r}")
        axis = tuple(float(a) for a in self.view_axis)
        n = math.sqrt(sum(a * a for a in axis))
        if len(axis) != 3 or not math.isfinite(n) or abs(n - 1.0) > 1e-6:
            raise ConfigError(f"view_axis must be a unit 3-vector, got {self.view_axis!r}")

    @classmethod
    def unimpaired(cls) -> Impairments:
        """A world without the impairments: the robot knows the true goal, no link delay, and
        the robot seen as precisely along the view as across it (the lateral sd)."""
        lateral = cls().lateral_sigma_m
        return cls(goal_sigma_m=0.0, delay_s=0.0, depth_sigma_m=lateral, lateral_sigma_m=lateral)

    def describe(self) -> str:
        """One line for a status or a log."""
        a = ", ".join(f"{v:g}" for v in self.view_axis)
        return (
            f"goal noise {1000 * self.goal_sigma_m:g} mm, delay {1000 * self.delay_s:g} ms each "
            f"way, single view along ({a}): depth {1000 * self.depth_sigma_m:g} mm, lateral "
            f"{1000 * self.lateral_sigma_m:g} mm"
        )

    def replace(self, **changes: Any) -> Impairments:
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["view_axis"] = list(self.view_axis)
        return d


class CommandDelay:
    """The command path of the teleoperation delay: the hands (a batch) as the robot receives
    them, `ticks` ticks late (the start hand until then).

    Args:
        start: the hands at the start (batch (N,)).
        ticks: the delay in ticks, >= 0 (round(delay_s / dt)).
    """

    def __init__(self, start: HandState, ticks: int) -> None:
        if ticks < 0:
            raise ConfigError(f"a delay of {ticks} ticks")
        self.ticks = ticks
        self._queue: deque[HandState] = deque([start] * ticks)

    def push(self, hand: HandState) -> HandState:
        """Send the hands of this tick; the hands the robot receives this tick."""
        if self.ticks == 0:
            return hand
        self._queue.append(hand)
        return self._queue.popleft()

    def select(self, keep: NDArray[np.bool_]) -> None:
        """Keep only the rows `keep`."""
        self._queue = deque(H.take(keep) for H in self._queue)
