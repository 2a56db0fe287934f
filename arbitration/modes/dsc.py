"""`DSC`, DS with the robot's confidence per dimension: eq (8) on a tempered P(R_i).

    P~(R_i)  = c_i^power * P(R_i)
    alpha_i  = cap_g * (DS's windowed eq (8) with P~(R_i) for P(R_i))

with c_i in [0, 1] the robot's confidence in dimension i of its goal
(`Quantities.confidence`: `belief.GoalBelief.confidence`, from the belief over the candidate
goals and their pose uncertainty; docs/METHOD.md §10) and the robot's goal the belief's MAP
candidate (the caller's `X_goal`). Where the robot does not know where the goal is along a
dimension, it expects little control there and eq (8) gives the person that dimension;
where the likely candidates agree, it helps as DS does. DS's windows, B and caps are
unchanged (the windows are DSC's own state), and DSC reports the tempered P(R) it used, as
DS reports its filtered B.

With c_i = 1 everywhere (a goal it is told: `ArbitrationInput.confidence=None`) it is DS to
the last bit whatever `power` (1^power = 1, x * 1.0 == x), and at power = 0 it is DS whatever
the confidence. Its own parameters are DS's caps and the tempering's exponent `power` in
[0, 10] (1: the plain product).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from dsteleop.arbitration.modes import ds
from dsteleop.arbitration.modes.base import ModeSpec, Quantities, Rows, check_range

NAME = "DSC"


@dataclass(frozen=True)
class DSCParams:
    """DSC's own parameters (module docstring).

    Attributes:
        cap_translation, cap_rotation, cap_fingers: DS's authority caps per group, in (0, 1].
        power: the exponent of c_i in the tempering, in [0, 10].
    """

    cap_translation: float = 1.0
    cap_rotation: float = 1.0
    cap_fingers: float = 1.0
    power: float = 1.0

    def __post_init__(self) -> None:
        for name in ("cap_translation", "cap_rotation", "cap_fingers"):
            check_range(NAME, name, getattr(self, name), 0.0, 1.0)
        check_range(NAME, "power", self.power, 0.0, 10.0, low_open=False)


@functools.lru_cache(maxsize=64)
def _as_ds(params: DSCParams) -> ds.DSParams:
    """DS's parameters with DSC's caps (cached: asked for every tick)."""
    return ds.DSParams(params.cap_translation, params.cap_rotation, params.cap_fingers)


def alpha(params: DSCParams, q: Quantities, rows: Rows, state: ds.Windows) -> ds.Windows:
    """DS's rule (`ds.alpha`) on P(R_i) tempered by the confidence c_i ** power."""
    c = q.confidence[rows]
    q.P_robot[rows] = q.P_robot[rows] * (c if params.power == 1.0 else c**params.power)
    return ds.alpha(_as_ds(params), q, rows, state)


SPEC = ModeSpec(
    NAME,
    "DSC",
    alpha,
    "DS with P(R_i) tempered by the robot's confidence c_i in each dimension of its goal",
    params=DSCParams,
    space=(
        *(s for s in ds.SPEC.space if not s.startswith(f"{ds.NAME}.")),
        f"{NAME}.cap_translation=0.05:1",
        f"{NAME}.cap_rotation=0.05:1",
        f"{NAME}.power=0:4",
    ),
    initial_state=ds.initial_state,
    shorthands=(("cap", ("cap_translation", "cap_rotation", "cap_fingers")),),
    reads_confidence=True,
)
