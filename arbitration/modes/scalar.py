"""`scalar`, the S-tuned baseline: one alpha for every dimension, eq (3) with a cap and a scale.

    alpha = cap * (1 - erf(scale * |p_goal - p_cur|_1 / max(|p_goal - p_start|_1, floor)))

with the robot's position (p_cur), its segment start (p_start) and eq (3)'s floor
(`alloc_floor_m`). `cap` in (0, 1] bounds the robot's authority, `scale` in (0, 100] says how
fast it falls with the distance still to go (scale < 1: assistance reaches further from the
goal; > 1: it is kept for the end game). With cap = 1 and scale = 1 it is S, eq (3), to the
last bit. It is DS's fair competitor (docs/METHOD.md §5): a scalar alpha with hyper-parameters
of its own, tuned with the same budget (`dsteleop tune --mode scalar`), so that DS beating it
says something about the per-dimension idea and not only about tuning.
"""

from __future__ import annotations

from dataclasses import dataclass

from dsteleop.arbitration.allocation import standard_alpha_of
from dsteleop.arbitration.jit import kernel
from dsteleop.arbitration.modes.base import Array, ModeSpec, Quantities, Rows, check_range

NAME = "scalar"


@dataclass(frozen=True)
class ScalarParams:
    """The scalar baseline's own parameters (module docstring).

    Attributes:
        cap: the largest alpha, in (0, 1].
        scale: the erf argument's factor, in (0, 100].
    """

    cap: float = 1.0
    scale: float = 1.0

    def __post_init__(self) -> None:
        check_range(NAME, "cap", self.cap, 0.0, 1.0)
        check_range(NAME, "scale", self.scale, 0.0, 100.0)


@kernel
def capped_standard_rows(
    l1_cur: Array, l1_start: Array, cap: float, scale: float, rows: Rows, alpha: Array
) -> None:
    """alpha[m, :] = cap * eq (3) at scale * the distance, for the batch rows `rows` (the
    denominator l1_start is floored already)."""
    for k in range(rows.shape[0]):
        m = rows[k]
        a = cap * standard_alpha_of(scale * l1_cur[m], l1_start[m], 0.0)
        for i in range(alpha.shape[1]):
            alpha[m, i] = a


def alpha(params: ScalarParams, q: Quantities, rows: Rows, state: None) -> None:
    capped_standard_rows(
        q.l1_goal_current_m,
        q.l1_goal_start_m,
        float(params.cap),
        float(params.scale),
        rows,
        q.alpha,
    )


SPEC = ModeSpec(
    NAME,
    "SCALAR",
    alpha,
    "cap * eq (3) at scale * the distance: S with a cap and a scale (the S-tuned baseline)",
    params=ScalarParams,
    space=(f"{NAME}.cap=0.05:1", f"{NAME}.scale=log:0.2:5"),
    reads_allocation=False,
)
