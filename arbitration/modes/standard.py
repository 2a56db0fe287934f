"""`S`, the standard controller, eq (3): one alpha for every dimension, from position only.

    alpha = 1 - erf(|p_goal - p_cur|_1 / max(|p_goal - p_start|_1, floor))

It is the scalar baseline (`scalar.py`) at cap = 1 and scale = 1, with no parameters of its
own (the floor is `alloc_floor_m`, shared with eq (4)).
"""

from __future__ import annotations

from dsteleop.arbitration.modes.base import ModeSpec, Quantities, Rows
from dsteleop.arbitration.modes.scalar import capped_standard_rows


def alpha(params: None, q: Quantities, rows: Rows, state: None) -> None:
    capped_standard_rows(q.l1_goal_current_m, q.l1_goal_start_m, 1.0, 1.0, rows, q.alpha)


SPEC = ModeSpec(
    "S",
    "S",
    alpha,
    "eq (3): one alpha for all dimensions from the position",
    reads_allocation=False,
)
