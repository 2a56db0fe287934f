"""`DS`, dimension-specific shared autonomy, eq (8), with its moving windows.

    B_f,i    = mean of B_i over the last `window` ticks (the window starts full of ones, so B
               starts at 1)
    a_i      = clip((P(R_i) - P(H_i)) * B_f,i + P(H_i), 0, 1)                            (8)
    alpha_i  = cap_g * (mean of a_i over the last min(ticks seen, window) ticks)

where g is the dimension's group (translation, rotation, fingers) and cap_g in (0, 1] DS's
own authority cap for it (`DSParams`; the windows hold the uncapped a_i). The caps are the
same lever as the scalar baseline's `cap` (alpha = cap * eq (3)), per group: a baseline and
DS tuned with equal levers (issue 31). At their defaults (1.0) DS is the paper's eq (8) to
the last bit (x * 1.0 == x). `DS.cap=X` is a shorthand that sets all three.

The windows are DS's own filter state (`Windows`), over the rows of the batch that run DS:
every row, or in a batch that mixes modes its own rows only (the rows of other modes have none
to keep; a tick copies the windows of DS's rows, not of the whole batch); they restart, with
the segment, at each new goal (`Arbiter.initial_state`). DS reports the filtered B. Its
parameters are the shared ones its alpha depends on (kappa of eq (5), p, q, b of eq (7),
`window`), fields of `ArbitrationConfig`, and its own caps (`DS.cap_translation`,
`DS.cap_rotation`, `DS.cap_fingers`); its default tuning space searches them, and the
translation and rotation caps over the scalar's cap range (the planar study has no fingers).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.allocation import ds_alpha_of
from dsteleop.arbitration.jit import kernel
from dsteleop.arbitration.modes.base import Array, ModeSpec, Quantities, Rows, check_range
from dsteleop.errors import ContractError

if TYPE_CHECKING:
    from dsteleop.arbitration.config import ArbitrationConfig

NAME = "DS"


@dataclass(frozen=True)
class DSParams:
    """DS's own parameters: its authority cap per group of dimensions (module docstring).

    Attributes:
        cap_translation: the largest alpha of x, y, z, in (0, 1].
        cap_rotation: the largest alpha of the three rotation dimensions, in (0, 1].
        cap_fingers: the largest alpha of each finger's openness, in (0, 1].
    """

    cap_translation: float = 1.0
    cap_rotation: float = 1.0
    cap_fingers: float = 1.0

    def __post_init__(self) -> None:
        for name in ("cap_translation", "cap_rotation", "cap_fingers"):
            check_range(NAME, name, getattr(self, name), 0.0, 1.0)


@functools.lru_cache(maxsize=64)
def caps(params: DSParams, dims: int) -> Array:
    """(dims,) the cap of each dimension: translation x 3, rotation x 3, fingers x F
    (read-only, cached: asked for every tick)."""
    F = dims - 6
    groups = (params.cap_translation,) * 3 + (params.cap_rotation,) * 3
    out = np.array(groups + (params.cap_fingers,) * F, dtype=np.float64)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Windows:
    """DS's moving windows over the last W ticks, for M' rows of a batch of M: every row
    (`rows` None, M' = M) or the batch rows `rows` (a batch that mixes modes: DS's own).

    Each window is an array (W, M', 6 + F), oldest tick first, read-only: a tick makes new
    windows (the last W - 1 rows and its own), so an earlier state stays valid.

    Attributes:
        alpha_window: raw alpha samples (eq 8 on the filtered B, clipped); zeros before the
            first tick (the mean divides by min(count, W) filled samples).
        B_window: raw willingness samples (eq 7); the window starts full of ones.
        count: ticks DS has stepped these windows.
        rows: the batch rows the windows' rows are of, ascending (None: row m of the batch).
    """

    alpha_window: Array
    B_window: Array
    count: int
    rows: NDArray[np.intp] | None = None

    def select(self, keep: NDArray[np.bool_]) -> Windows:
        """The windows of the batch rows `keep` (a mask over the batch)."""
        if self.rows is None:
            mine, rows = keep, None
        else:  # its rows that stay, numbered in the kept batch
            mine = keep[self.rows]
            rows = (np.cumsum(keep) - 1)[self.rows[mine]]
        a, b = self.alpha_window[:, mine], self.B_window[:, mine]
        a.flags.writeable = b.flags.writeable = False
        return Windows(a, b, self.count, rows)

    def of_rows(self, rows: Rows) -> Windows:
        """The windows of the batch rows `rows` (ascending): these, or their rows taken."""
        if self.rows is None:
            if rows.shape[0] == self.alpha_window.shape[1]:  # every row: its own windows
                return self
            index = rows
        elif self.rows is rows:  # the tick's rows, as the last tick's (the common case)
            return self
        elif np.array_equal(self.rows, rows):  # the same rows: kept as the tick's object
            return Windows(self.alpha_window, self.B_window, self.count, rows)
        else:
            index = np.searchsorted(self.rows, rows)
            if np.any(index >= self.rows.shape[0]) or not np.array_equal(self.rows[index], rows):
                raise ContractError("DS's windows hold no state for some of the tick's rows")
        a, b = self.alpha_window[:, index], self.B_window[:, index]
        a.flags.writeable = b.flags.writeable = False
        return Windows(a, b, self.count, rows)


def initial_state(config: ArbitrationConfig, dims: int, M: int) -> Windows:
    zeros, ones = np.zeros((config.window, M, dims)), np.ones((config.window, M, dims))
    zeros.flags.writeable = ones.flags.writeable = False
    return Windows(zeros, ones, 0)


def alpha(params: DSParams, q: Quantities, rows: Rows, state: Windows) -> Windows:
    own = state.of_rows(rows)
    new_alpha, new_B = _windows_rows(
        q.P_robot, q.P_human, q.B, q.alpha,
        _read_only(own.alpha_window), _read_only(own.B_window), own.count, rows,
        caps(params, q.alpha.shape[1]),
    )  # fmt: skip
    new_alpha.flags.writeable = new_B.flags.writeable = False
    return Windows(new_alpha, new_B, own.count + 1, own.rows)


def _read_only(window: Array) -> Array:
    """The window as the kernel always receives it (one compiled version): read-only."""
    if not window.flags.writeable:
        return window
    view = window.view()
    view.flags.writeable = False
    return view


@kernel
def _windows_rows(
    P_r: Array, P_h: Array, B: Array, alpha: Array, alpha_window: Array, B_window: Array,
    count: int, rows: Rows, cap: Array,
) -> tuple[Array, Array]:  # fmt: skip
    """Eq (8) on the windows for the batch rows `rows`, whose windows are the windows' rows
    in order (row k of a window is batch row rows[k]): writes alpha (times its dimension's
    `cap`, after the window) and the filtered B into their batch rows, returns the new
    windows."""
    W, n, D = B_window.shape
    new_alpha, new_B = np.empty((W, n, D)), np.empty((W, n, D))
    new_alpha[: W - 1] = alpha_window[1:]
    new_B[: W - 1] = B_window[1:]
    for k in range(rows.shape[0]):
        m = rows[k]
        for i in range(D):
            B_f = B_window[1, k, i] if W > 1 else 0.0
            for w in range(2, W):
                B_f += B_window[w, k, i]
            B_f = (B_f + B[m, i]) / W if W > 1 else B[m, i] / W
            a_raw = ds_alpha_of(P_r[m, i], P_h[m, i], B_f)
            a_sum = alpha_window[1, k, i] if W > 1 else 0.0
            for w in range(2, W):
                a_sum += alpha_window[w, k, i]
            a_sum = a_sum + a_raw if W > 1 else a_raw
            new_B[W - 1, k, i] = B[m, i]
            new_alpha[W - 1, k, i] = a_raw
            alpha[m, i] = cap[i] * (a_sum / min(count + 1, W))
            B[m, i] = B_f  # the filtered B is the one reported
    return new_alpha, new_B


SPEC = ModeSpec(
    NAME,
    "DS",
    alpha,
    "eq (8) per dimension, on moving windows of B and alpha, with a cap per group",
    params=DSParams,
    space=(
        "kappa=log:1:40",
        "p=log:1.5:12",
        "q=log:1.5:12",
        "b=log:0.25:4",
        "window=int:1:15",
        f"{NAME}.cap_translation=0.05:1",
        f"{NAME}.cap_rotation=0.05:1",
    ),
    initial_state=initial_state,
    shorthands=(("cap", ("cap_translation", "cap_rotation", "cap_fingers")),),
)
