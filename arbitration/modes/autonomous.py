"""`autonomous`: alpha = 1 on every dimension, the robot's policy alone."""

from __future__ import annotations

from dsteleop.arbitration.modes.base import ModeSpec, Quantities, Rows


def alpha(params: None, q: Quantities, rows: Rows, state: None) -> None:
    q.alpha[rows] = 1.0


SPEC = ModeSpec(
    "autonomous",
    "AUTONOMOUS",
    alpha,
    "alpha = 1: the robot's policy alone",
    reads_allocation=False,
)
