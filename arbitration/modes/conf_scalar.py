"""`conf_scalar`, the confidence-scaled scalar baseline (Dragan & Srinivasa's form): one alpha
for every dimension, the scalar baseline scaled by a function of the robot's confidence.

    f(c)   = clip((c - threshold) / (1 - threshold), 0, 1)
    alpha  = cap * f(c_joint) * (1 - erf(scale * |p_goal - p_cur|_1 / max(|p_goal - p_start|_1,
                                                                          floor)))

with c_joint in [0, 1] the robot's confidence in its whole goal at once (`Quantities.
confidence_joint`: `belief.GoalBelief.confidence`, the probability that the true goal is
within the task's tolerance of the MAP goal in every dimension; docs/METHOD.md §10). Dragan
& Srinivasa (2013) make the arbitration a function of the robot's confidence in its
prediction, a linear ramp from a threshold in their study's "timid" and "aggressive" forms;
the distance term keeps the scalar baseline's lever (`scalar`), so `conf_scalar` against
`DSC` compares one scalar of confidence with one per dimension, with the same levers (cap,
scale; DSC has DS's caps). With c_joint = 1 and threshold = 0 it is `scalar` to the last bit
(f = 1, cap * 1.0 == cap).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dsteleop.arbitration.allocation import standard_alpha_of
from dsteleop.arbitration.jit import kernel
from dsteleop.arbitration.modes.base import Array, ModeSpec, Quantities, Rows, check_range

NAME = "conf_scalar"


@dataclass(frozen=True)
class ConfScalarParams:
    """The confidence-scaled scalar's own parameters (module docstring).

    Attributes:
        cap: the largest alpha, in (0, 1].
        scale: the erf argument's factor, in (0, 100].
        threshold: the confidence below which alpha is 0, in [0, 0.95].
    """

    cap: float = 1.0
    scale: float = 1.0
    threshold: float = 0.0

    def __post_init__(self) -> None:
        check_range(NAME, "cap", self.cap, 0.0, 1.0)
        check_range(NAME, "scale", self.scale, 0.0, 100.0)
        check_range(NAME, "threshold", self.threshold, 0.0, 0.95, low_open=False)


@kernel
def _rows(
    l1_cur: Array, l1_start: Array, conf: Array, cap: float, scale: float, threshold: float,
    rows: Rows, alpha: Array,
) -> None:  # fmt: skip
    for k in range(rows.shape[0]):
        m = rows[k]
        f = min(1.0, max(0.0, (conf[m] - threshold) / (1.0 - threshold)))
        a = (cap * f) * standard_alpha_of(scale * l1_cur[m], l1_start[m], 0.0)
        for i in range(alpha.shape[1]):
            alpha[m, i] = a


def alpha(params: ConfScalarParams, q: Quantities, rows: Rows, state: None) -> None:
    _rows(
        q.l1_goal_current_m, q.l1_goal_start_m, _contiguous(q.confidence_joint),
        float(params.cap), float(params.scale), float(params.threshold), rows, q.alpha,
    )  # fmt: skip


def _contiguous(a: Array) -> Array:
    """The array as the kernel takes it (one compiled version: C-contiguous, writable)."""
    if a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=np.float64, order="C")


SPEC = ModeSpec(
    NAME,
    "CONF_SCALAR",
    alpha,
    "cap * f(confidence) * eq (3) at scale * the distance: Dragan's confidence-scaled scalar",
    params=ConfScalarParams,
    space=(f"{NAME}.cap=0.05:1", f"{NAME}.scale=log:0.2:5", f"{NAME}.threshold=0:0.9"),
    reads_allocation=False,
    reads_confidence=True,
)
