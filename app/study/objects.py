"""The objects world: several objects, the person wants one, the robot is not told which.

Issue 32's question: a robot that infers the person's goal among K candidates from the
person's hand (a belief over the candidates, `arbitration/belief.py`) and knows each
candidate's pose only up to its own perception error. docs/operator.md, "The objects world",
gives every value's source; the values were written down and committed before any mode was
compared in this world.

    objects        K objects in a row along the base's y axis (side by side, across the
                   scene camera's view), `spacing_m` apart, centred on the study's handle,
                   every one with the handle's grasp normal (utensils in one holder lie
                   parallel); the task succeeds within the success radius of the object the
                   person wants (at the end of the run) and the heading tolerance of its normal
    the person     wants one object, drawn uniformly per run; with probability `change_share`
                   it changes its mind once, at a time drawn from U(`change_at_s`), to one of
                   the others (uniformly); otherwise it is the default world's person
    the robot      perceives every object once per run through the scene camera (the person's
                   view, `Impairments.view_axis`): its error has sd `perception_depth_m` along
                   the view and `perception_lateral_m` across it, and `perception_heading_rad`
                   in the heading; it keeps a belief over the objects from the hand it receives
                   (the study's `ArbitrationConfig.belief`, uniform prior), seeks the MAP
                   object's perceived pose and knows its own error model (the belief's
                   per-axis sigma: the error's sd along each base axis)

The goal noise of the default world (`Impairments.goal_sigma_m`) stays an independent axis: an
error the robot does not know about (the `objects` preset sets it to 0).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import ConfigError

Array = NDArray[np.float64]

#: The most objects a world may hold (the belief's floor needs K * epsilon < 1).
MAX_OBJECTS = 9


@dataclass(frozen=True)
class Objects:
    """The objects world's objects, the robot's perception and the person's changes of mind
    (module docstring; docs/operator.md gives the sources).

    Attributes:
        count: K, the number of objects, in [1, MAX_OBJECTS] (1: nothing to infer).
        spacing_m: the distance between neighbouring objects [m], in (0, 0.3].
        perception_depth_m: sd of the robot's perceived object position along the scene
            camera's view [m], >= 0.
        perception_lateral_m: ... across the view [m], >= 0.
        perception_heading_rad: sd of the perceived heading of each object [rad], >= 0.
        change_share: the share of runs in which the person changes its mind once, in [0, 1].
        change_at_s: (lo, hi): the time of the change is drawn from U(lo, hi) [s], 0 <= lo
            <= hi.
    """

    count: int = 3
    spacing_m: float = 0.08
    perception_depth_m: float = 0.02
    perception_lateral_m: float = 0.005
    perception_heading_rad: float = 0.05
    change_share: float = 0.2
    change_at_s: tuple[float, float] = (1.5, 3.0)

    def __post_init__(self) -> None:
        k = self.count
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= MAX_OBJECTS:
            raise ConfigError(f"objects: count must be an integer in [1, {MAX_OBJECTS}], got {k!r}")
        _number("spacing_m", self.spacing_m, 0.0, 0.3, low_open=True)
        for name in ("perception_depth_m", "perception_lateral_m"):
            _number(name, getattr(self, name), 0.0, 0.2)
        _number("perception_heading_rad", self.perception_heading_rad, 0.0, math.pi / 2)
        _number("change_share", self.change_share, 0.0, 1.0)
        pair = tuple(self.change_at_s)
        lo, hi = pair if len(pair) == 2 else (math.nan, math.nan)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
            raise ConfigError(
                f"objects: change_at_s must be an interval 0 <= lo <= hi [s], got "
                f"{self.change_at_s!r}"
            )

    def check(self, success_radius_m: float, operator_tolerance_m: float) -> None:
        """Refuse objects that are not distinct: each object must lie outside the task's
        success radius and the person's own tolerance around its neighbour (grasping a
        neighbour is then a failure, and a person satisfied at one is not at the other)."""
        need = success_radius_m + operator_tolerance_m
        if self.count > 1 and self.spacing_m <= need:
            raise ConfigError(
                f"objects: spacing {self.spacing_m:g} m is within the task's radius and the "
                f"person's tolerance ({need:g} m): the objects would not be distinct"
            )

    def positions(self, centre_xy_m: tuple[float, float]) -> Array:
        """(K, 2) the objects' true x, y [m]: a row along base y centred on `centre_xy_m`."""
        offsets = (np.arange(self.count) - (self.count - 1) / 2.0) * self.spacing_m
        return np.stack([np.full(self.count, centre_xy_m[0]), centre_xy_m[1] + offsets], -1)

    def perception_sd(self, view_axis: tuple[float, float, float]) -> Array:
        """(3,) the sd of the perceived x, y [m] and heading [rad] along the base axes: the
        camera's covariance lateral^2 I + (depth^2 - lateral^2) a a^T read on its diagonal
        (exact for a view along a base axis, as the study's; the belief takes one sigma per
        axis)."""
        a = np.asarray(view_axis, dtype=np.float64)[:2]
        lat, dep = self.perception_lateral_m, self.perception_depth_m
        var = lat * lat + (dep * dep - lat * lat) * a * a
        return np.array([math.sqrt(var[0]), math.sqrt(var[1]), self.perception_heading_rad])

    def perception_error(self, view_axis: tuple[float, float, float], z: Array) -> Array:
        """Perception errors (..., 3) of x, y [m] and heading [rad] from standard normal
        draws z (..., 3): sd `perception_depth_m` along the view (its planar part),
        `perception_lateral_m` across it, `perception_heading_rad` in the heading."""
        a = np.asarray(view_axis, dtype=np.float64)[:2]
        n = float(np.linalg.norm(a))
        a = a / n if n > 0 else np.array([1.0, 0.0])
        lat, dep = self.perception_lateral_m, self.perception_depth_m
        xy = z[..., :2]
        along = xy @ a
        pos = lat * xy + (dep - lat) * along[..., None] * a
        return np.concatenate([pos, self.perception_heading_rad * z[..., 2:3]], -1)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["change_at_s"] = list(self.change_at_s)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Objects:
        d = dict(d)
        if "change_at_s" in d:
            d["change_at_s"] = tuple(d["change_at_s"])
        return cls(**d)


def _number(name: str, v: Any, low: float, high: float, low_open: bool = False) -> None:
    """A finite number in [low, high] (or (low, high]); else a ConfigError naming it."""
    ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    if not ok or (v <= low if low_open else v < low) or v > high:
        bracket = "(" if low_open else "["
        raise ConfigError(
            f"objects: {name} must be a number in {bracket}{low:g}, {high:g}], got {v!r}"
        )
