"""`manual`: alpha = 0 on every dimension, the robot moves exactly as the hand does."""

from __future__ import annotations

from dsteleop.arbitration.modes.base import ModeSpec, Quantities, Rows


def alpha(params: None, q: Quantities, rows: Rows, state: None) -> None:
    q.alpha[rows] = 0.0


SPEC = ModeSpec("manual", "MANUAL", alpha, "alpha = 0: the hand alone", reads_allocation=False)
