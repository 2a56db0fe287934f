"""The disagreement world: a handle with more than one right way to grasp it.

The paper's question is about disagreement between two agents that are both right: "neither
agent is incorrect", the operator prefers another approach ("grasp the object from the side
rather than the top", Fig. 1), and a robot that over-dominates that dimension makes the
person fight it. In the study's default world the person's own heading lies inside the
task's tolerance around the robot's, so no disagreement matters there. `Grasps` makes one that
does (docs/operator.md, "The disagreement world", gives every value's source):

    grasps         two named grasps of the handle, `top` at the grasp normal and `side` at the
                   normal - `separation_rad`; the task succeeds within the success radius of
                   the handle and within the heading tolerance of EITHER grasp
    robot          the robot's policy goes to one of them (`robot_grasp`, default `top`)
    person         prefers the robot's grasp with probability `prefer_robot_share`, else the
                   other one, and aims for its own grasp's heading within its own tolerance
    adaptation     at each resistance pause (the robot resisted three submovements in a row),
                   it switches to the robot's grasp with probability `alpha`, its own
                   adaptability, drawn from U(`adaptability`) per person (the bounded-memory
                   adaptation model of Nikolaidis, Hsu and Srinivasa, IJRR 2017 and HRI 2017:
                   after a disagreement a person switches to the robot's way with probability
                   alpha, under a uniform prior over alpha); so it settles after a geometric
                   number of pauses, each of which costs it time, and a person who never
                   adapts keeps its own grasp until its patience runs out

The separation is a quarter turn (pi / 2): a side grasp of a handle is perpendicular to a top
grasp. Both grasps are then as far from the start heading (0) as each other (pi / 4 each way),
and neither agent's grasp lies within the other's tolerance (0.35 rad for the task, 0.175 for
the person). The robot's goal position noise stays a separate axis of the world
(`Impairments.goal_sigma_m`); the `disagreement` preset of the command line sets it to 0: both
agents are right.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from dsteleop.errors import ConfigError

#: The grasps' names, in order: `top` at the grasp normal, `side` a separation away.
GRASP_NAMES: tuple[str, ...] = ("top", "side")


@dataclass(frozen=True)
class Grasps:
    """The disagreement world's grasps and the people's preferences (module docstring).

    Attributes:
        separation_rad: the side grasp's heading is the normal's minus this [rad].
        robot_grasp: the grasp the robot's policy goes to (`top` or `side`).
        prefer_robot_share: the share of people who prefer the robot's grasp, in [0, 1].
        adaptability: (lo, hi): each person's alpha is drawn from U(lo, hi), 0 <= lo <= hi
            <= 1.
    """

    separation_rad: float = math.pi / 2
    robot_grasp: str = "top"
    prefer_robot_share: float = 0.5
    adaptability: tuple[float, float] = (0.0, 1.0)

    def __post_init__(self) -> None:
        s = self.separation_rad
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not 0 < s <= math.pi:
            raise ConfigError(f"grasp separation must be in (0, pi] rad, got {s!r}")
        if self.robot_grasp not in GRASP_NAMES:
            raise ConfigError(
                f"unknown grasp {self.robot_grasp!r} (choose from {', '.join(GRASP_NAMES)})"
            )
        share = self.prefer_robot_share
        if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 <= share <= 1:
            raise ConfigError(f"prefer-robot share must be in [0, 1], got {share!r}")
        pair = tuple(self.adaptability)
        lo, hi = pair if len(pair) == 2 else (math.nan, math.nan)
        if not 0 <= lo <= hi <= 1:
            raise ConfigError(
                f"adaptability must be an interval 0 <= lo <= hi <= 1, got {self.adaptability!r}"
            )

    def check(self, success_heading_rad: float, operator_tolerance_rad: float) -> None:
        """Refuse grasps that do not disagree: each agent's grasp must lie outside the other's
        tolerance (the task's heading tolerance plus the person's own)."""
        need = success_heading_rad + operator_tolerance_rad
        if self.separation_rad <= need:
            raise ConfigError(
                f"grasp separation {self.separation_rad:g} rad is within the task's and the "
                f"person's heading tolerances ({need:g} rad): the grasps would not disagree"
            )

    def offsets_rad(self) -> tuple[float, ...]:
        """Each grasp's heading minus the normal's, in GRASP_NAMES order [rad]."""
        return (0.0, -float(self.separation_rad))

    def offset_of(self, name: str) -> float:
        return self.offsets_rad()[GRASP_NAMES.index(name)]

    @property
    def robot_index(self) -> int:
        return GRASP_NAMES.index(self.robot_grasp)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["adaptability"] = list(self.adaptability)
        d["names"] = list(GRASP_NAMES)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Grasps:
        d = {k: v for k, v in d.items() if k != "names"}
        if "adaptability" in d:
            d["adaptability"] = tuple(d["adaptability"])
        return cls(**d)


def settle_after(rng_uniform: float, alpha: float, never: int) -> int:
    """The resistance pause (1, 2, ...) at which a person of adaptability `alpha` switches to
    the robot's grasp: geometric with success probability alpha, from one uniform draw by
    inversion; `never` for alpha = 0 (and capped there)."""
    if alpha <= 0.0:
        return never
    if alpha >= 1.0:
        return 1
    k = 1 + math.floor(math.log1p(-rng_uniform) / math.log1p(-alpha))
    return int(min(max(k, 1), never))
