"""The arbiter: one tick of eq (1)-(8) for any mode, on a batch of any size.

One tick, for every dimension i of 6 + F (the maths of each line is stated in `policy.py`
and `allocation.py`):

    U_robot = sat(K_r * diff(X_goal, X_current))                  goal-seeking policy
    U_human = sat(diff(X_human, X_human_prev) / dt)                the hand's own motion
    P(H), P(R), psi_human, psi_robot, B                            eq (4)-(7)
    alpha_i = mode-specific (below)
    U_out   = alpha * U_robot + (1 - alpha) * U_human              (1)
    X_next  = advance_reference(X_ref, X_current, U_out, dt)       (2)

Modes: `manual` alpha = 0; `autonomous` alpha = 1; `S` eq (3), one alpha for all dims;
`DS` eq (8), with a moving-average window over B_i and alpha_i (B's window starts full of
ones: B starts at 1). Every mode computes P(H), P(R), psi and B, so a viewer or a recorder
sees the same quantities whatever the mode.

All arrays may carry a leading batch shape (the states broadcast against each other; the
filter state is made for the tick's batch shape); the loop runs a batch of one, the
simulation study thousands of trajectories.
"""

from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import policy
from dsteleop.arbitration.allocation import (
    allocation_linear,
    allocation_rotation,
    ds_alpha_of,
    speed_change_of,
    standard_alpha_of,
    unit_directions_into,
    willingness_of,
)
from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.jit import as_input, kernel
from dsteleop.arbitration.policy import bound_into, human_action_into, robot_action_into
from dsteleop.arbitration.se3 import (
    HandState,
    batch_of,
    diff_into,
    integrate_into,
    row,
    state_input,
)
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]


class Mode(str, enum.Enum):
    """Arbitration mode."""

    DS = "DS"
    S = "S"
    MANUAL = "manual"
    AUTONOMOUS = "autonomous"

    @classmethod
    def parse(cls, text: str) -> Mode:
        for m in cls:
            if text.lower() == m.value.lower() or text.upper() == m.name:
                return m
        names = ", ".join(m.value for m in cls)
        raise ConfigError(f"unknown mode {text!r} (choose from {names})")


@dataclass(frozen=True)
class ArbitrationInput:
    """Everything one tick needs; all states in the robot base frame.

    Attributes:
        X_human: the operator's mapped hand now.
        X_human_prev: the operator's mapped hand one tick ago.
        X_human_start: the operator's hand when the active goal started.
        X_current: the robot's achieved state now.
        X_prev: the robot's achieved state one tick ago.
        X_start: the robot's state when the active goal started.
        X_goal: the goal the robot knows.
        dt: tick length [s].
        history_term: (6 + F,) mean unit direction of previous attempts (eq 6), shared by
            every row, or (..., 6 + F) one per row of the batch (each row its own
            operator); None if none.
        X_ref: the commanded reference eq (2) integrates from (the previous X_next); None
            for a kinematic plant, whose reference is X_current.
    """

    X_human: HandState
    X_human_prev: HandState
    X_human_start: HandState
    X_current: HandState
    X_prev: HandState
    X_start: HandState
    X_goal: HandState
    dt: float
    history_term: Array | None = None
    X_ref: HandState | None = None


@dataclass(frozen=True)
class ArbitrationStep:
    """Result of one tick, each (..., 6 + F) except X_next."""

    alpha: Array
    P_human: Array
    P_robot: Array
    B: Array
    psi_human: Array
    psi_robot: Array
    U_human: Array
    U_robot: Array
    U_out: Array
    X_next: HandState


#: The per-dimension arrays of an `ArbitrationStep`, in the order recordings list them.
STEP_ARRAYS = (
    "alpha",
    "P_human",
    "P_robot",
    "B",
    "psi_human",
    "psi_robot",
    "U_human",
    "U_robot",
    "U_out",
)


@dataclass(frozen=True)
class FilterState:
    """Moving windows of the DS arbiter over the last W ticks, for a batch of M.

    Each window is an array (W, M, 6 + F), oldest tick first, read-only: a tick makes new
    windows (the last W - 1 rows and its own), so an earlier state stays valid.

    Attributes:
        alpha_window: raw alpha samples (eq 8 on the filtered B, clipped); zeros before the
            first tick (the mean divides by min(count, W) filled samples).
        B_window: raw willingness samples (eq 7); the window starts full of ones.
        count: ticks seen so far.
        batch: the batch shape (...) of the states it filters, M = prod(batch).
    """

    alpha_window: Array
    B_window: Array
    count: int
    batch: tuple[int, ...]

    @classmethod
    def initial(cls, window: int, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        M = math.prod(batch)
        zeros, ones = np.zeros((window, M, dims)), np.ones((window, M, dims))
        zeros.flags.writeable = ones.flags.writeable = False
        return cls(zeros, ones, 0, tuple(batch))

    @property
    def alpha_rows(self) -> tuple[Array, ...]:
        """The alpha window's W rows (M, 6 + F), oldest first."""
        return tuple(self.alpha_window)

    @property
    def B_rows(self) -> tuple[Array, ...]:
        """The B window's W rows (M, 6 + F), oldest first."""
        return tuple(self.B_window)

    def select(self, keep: NDArray[np.bool_]) -> FilterState:
        """The state of the batch rows `keep` (a mask on a one-axis batch)."""
        a, b = self.alpha_window[:, keep], self.B_window[:, keep]
        a.flags.writeable = b.flags.writeable = False
        return FilterState(a, b, self.count, (int(np.count_nonzero(keep)),))


#: The modes in the order of `RowModes.codes`.
MODES: tuple[Mode, ...] = tuple(Mode)


@dataclass(frozen=True)
class RowModes:
    """The mode of every row of a batch that mixes modes (flattened batch order).

    Attributes:
        codes: (M,) index of each row's mode in `MODES`.
    """

    codes: NDArray[np.int8]

    @classmethod
    def of(cls, modes: list[Mode] | tuple[Mode, ...]) -> RowModes:
        return cls(np.array([MODES.index(m) for m in modes], dtype=np.int8))

    def groups(self) -> list[tuple[Mode, NDArray[np.bool_]]]:
        """(mode, mask of its rows) for each mode present."""
        return [(m, self.codes == i) for i, m in enumerate(MODES) if (self.codes == i).any()]

    def select(self, keep: NDArray[np.bool_]) -> RowModes:
        """The modes of the rows `keep`."""
        return RowModes(self.codes[keep])


@dataclass(frozen=True)
class Arbiter:
    """One mode's arbitration: `state, step = arbiter.step(state, inp)`.

    Attributes:
        mode: the mode.
        config: the hyper-parameters.
    """

    mode: Mode = Mode.DS
    config: ArbitrationConfig = field(default_factory=ArbitrationConfig)

    def initial_state(self, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        """A fresh filter state (windows empty, B = 1): at start and at each new segment."""
        return FilterState.initial(self.config.window, dims, batch)

    def step(
        self, state: FilterState, inp: ArbitrationInput, rows: RowModes | None = None
    ) -> tuple[FilterState, ArbitrationStep]:
        """One tick (module docstring); the filter state changes in DS mode only.

        Args:
            state: the filter state (`initial_state`) for the tick's batch.
            inp: the tick's states.
            rows: a mode per batch row (a batch that mixes modes, as the simulation study
                steps every mode of a trajectory at once); None: every row in `mode`.

        Raises:
            ConfigError: the filter state was made for another batch shape or dimension count.
        """
        cfg = self.config
        states = (inp.X_human, inp.X_human_prev, inp.X_human_start, inp.X_current,
                  inp.X_prev, inp.X_start, inp.X_goal)  # fmt: skip
        batch = batch_of(*(X.batch for X in states))
        if inp.X_ref is not None and inp.X_ref.batch not in (batch, ()):
            raise ConfigError(f"X_ref of batch {inp.X_ref.batch} for a tick of batch {batch}")
        F = inp.X_current.n_fingers
        D = 6 + F
        if state.batch != batch or state.B_window.shape[2] != D:
            raise ConfigError(
                f"filter state for batch {state.batch} and {state.B_window.shape[2]} dims, "
                f"tick of batch {batch} and {D} dims"
            )
        M = math.prod(batch)
        if rows is None:
            codes = _MODE_CODE[self.mode]
            push = self.mode is Mode.DS
        else:
            if rows.codes.shape != (M,):
                raise ConfigError(f"modes for {rows.codes.shape} rows, tick of batch {batch}")
            codes = rows.codes
            push = bool((codes == _DS_CODE).any())
        dt = float(inp.dt)
        X_ref = inp.X_current if inp.X_ref is None else inp.X_ref
        history = np.zeros(D) if inp.history_term is None else inp.history_term
        arrays: tuple[Any, ...] = tuple(a for X in (*states, X_ref) for a in state_input(X, batch))
        out, p, R, g, alpha_w, B_w = _tick(  # type: ignore[call-arg]
            *arrays,
            as_input(history, batch, 1),
            codes,
            _per_dim_params(cfg, F, dt),
            dt, float(cfg.kappa), float(cfg.p), float(cfg.q), float(cfg.b),
            float(cfg.psi_robot_floor), float(cfg.alloc_floor_m), float(cfg.max_lead_m),
            float(cfg.max_lead_rad), policy.bound_needed(inp.X_ref is not None, dt, cfg),
            _read_only(state.alpha_window), _read_only(state.B_window), state.count, push, M,
        )  # fmt: skip
        if push:
            alpha_w.flags.writeable = B_w.flags.writeable = False
            state = FilterState(alpha_w, B_w, state.count + 1, state.batch)
        shape = (*batch, D)
        arrays_out: dict[str, Any] = {n: out[k].reshape(shape) for k, n in enumerate(STEP_ARRAYS)}
        X_next = HandState(p.reshape(*batch, 3), R.reshape(*batch, 3, 3), g.reshape(*batch, F))
        return state, ArbitrationStep(**arrays_out, X_next=X_next)


#: Each mode's code in `RowModes.codes` (its index in `MODES`), as the kernel reads it.
_MODE_CODE = {m: np.array([i], dtype=np.int8) for i, m in enumerate(MODES)}
_DS_CODE, _S_CODE, _AUTONOMOUS_CODE = (MODES.index(m) for m in (Mode.DS, Mode.S, Mode.AUTONOMOUS))
#: Rows of the kernel's scratch array of differences.
_GOAL_H, _GOAL_R, _PREV_H, _PREV_R, _START_H, _START_R = range(6)


def _read_only(window: Array) -> Array:
    """The window as the kernel always receives it (one compiled version): read-only."""
    if not window.flags.writeable:
        return window
    view = window.view()
    view.flags.writeable = False
    return view


@functools.lru_cache(maxsize=64)
def _per_dim_params(cfg: ArbitrationConfig, n_fingers: int, dt: float) -> Array:
    """The per-dimension vectors the kernel reads, (5, 6 + F): gains, v_max, the allocation
    floors, the one-tick and the from-start thresholds of eq (6)."""
    return np.stack(
        [
            cfg.gains(n_fingers),
            cfg.v_max(n_fingers),
            cfg.alloc_floor(n_fingers),
            cfg.still_step(n_fingers, dt),
            cfg.still_offset(n_fingers),
        ]
    )


@kernel
def _tick(
    Hp: Array, HR: Array, Hg: Array,  # X_human
    Pp: Array, PR: Array, Pg: Array,  # X_human_prev
    Sp: Array, SR: Array, Sg: Array,  # X_human_start
    Cp: Array, CR: Array, Cg: Array,  # X_current
    Qp: Array, QR: Array, Qg: Array,  # X_prev
    Tp: Array, TR: Array, Tg: Array,  # X_start
    Gp: Array, GR: Array, Gg: Array,  # X_goal
    Rp: Array, RR: Array, Rg: Array,  # X_ref
    history: Array, codes: NDArray[np.int8], params: Array,  # history (M or 1, 6 + F)
    dt: float, kappa: float, p: float, q: float, b: float, psi_floor: float,
    floor_m: float, max_lead_m: float, max_lead_rad: float, bounded: bool,
    alpha_window: Array, B_window: Array, count: int, push: bool, M: int,
) -> tuple[Array, Array, Array, Array, Array, Array]:  # fmt: skip
    """One tick of M rows (module docstring). Each input has M rows or one (shared).

    Returns the STEP_ARRAYS (9, M, 6 + F), X_next (position, rotation, openness) and the
    new alpha and B windows (W, M, 6 + F; empty when `push` is False).
    """
    F = Cg.shape[1]
    D = 6 + F
    W = B_window.shape[0]
    gains, v_max, floor, still_step, still_offset = (
        params[0],
        params[1],
        params[2],
        params[3],
        params[4],
    )
    out = np.empty((9, M, D))
    alpha, P_h, P_r, B, psi_h, psi_r, U_h, U_r, U_out = (
        out[0],
        out[1],
        out[2],
        out[3],
        out[4],
        out[5],
        out[6],
        out[7],
        out[8],
    )
    next_p, next_R, next_g = np.empty((M, 3)), np.empty((M, 3, 3)), np.empty((M, F))
    if push:
        new_alpha, new_B = np.empty((W, M, D)), np.empty((W, M, D))
        new_alpha[: W - 1] = alpha_window[1:]
        new_B[: W - 1] = B_window[1:]
    else:  # unused
        new_alpha, new_B = np.empty((0, 0, 0)), np.empty((0, 0, 0))
    # Rows of the scratch arrays: the six differences (to the goal, to the previous state,
    # to the start, per agent) and the two unit directions of eq (6).
    d, u = np.empty((6, D)), np.empty((2, D))
    for m in range(M):
        h, hp, hs = row(Hp.shape[0], m), row(Pp.shape[0], m), row(Sp.shape[0], m)
        c, cp, cs = row(Cp.shape[0], m), row(Qp.shape[0], m), row(Tp.shape[0], m)
        gl, rf = row(Gp.shape[0], m), row(Rp.shape[0], m)
        hr = row(history.shape[0], m)
        diff_into(Gp, GR, Gg, gl, Hp, HR, Hg, h, d, _GOAL_H)
        diff_into(Gp, GR, Gg, gl, Cp, CR, Cg, c, d, _GOAL_R)
        diff_into(Hp, HR, Hg, h, Pp, PR, Pg, hp, d, _PREV_H)
        diff_into(Cp, CR, Cg, c, Qp, QR, Qg, cp, d, _PREV_R)
        diff_into(Hp, HR, Hg, h, Sp, SR, Sg, hs, d, _START_H)
        diff_into(Cp, CR, Cg, c, Tp, TR, Tg, cs, d, _START_R)
        # The two actions (policy.py).
        human_action_into(d, _PREV_H, dt, v_max, U_h, m)
        robot_action_into(d, _GOAL_R, gains, v_max, U_r, m)
        # Eq (4)/(5): P(H), P(R); the goal-start distances are the robot's (its start).
        for i in range(D):
            if 3 <= i < 6:
                P_h[m, i] = allocation_rotation(d[_GOAL_H, i], kappa)
                P_r[m, i] = allocation_rotation(d[_GOAL_R, i], kappa)
            else:
                d_gs = Gp[gl, i] - Tp[cs, i] if i < 3 else Gg[gl, i - 6] - Tg[cs, i - 6]
                P_h[m, i] = allocation_linear(d[_GOAL_H, i], d_gs, floor[i])
                P_r[m, i] = allocation_linear(d[_GOAL_R, i], d_gs, floor[i])
        # Eq (6): psi per agent, from its own states; eq (7): B.
        unit_directions_into(d, _PREV_H, still_step, u, 0)
        unit_directions_into(d, _START_H, still_offset, u, 1)
        for i in range(D):
            psi_h[m, i] = speed_change_of(U_h[m, i], v_max[i], u[0, i], u[1, i], history[hr, i])
        unit_directions_into(d, _PREV_R, still_step, u, 0)
        unit_directions_into(d, _START_R, still_offset, u, 1)
        for i in range(D):
            psi_r[m, i] = speed_change_of(U_r[m, i], v_max[i], u[0, i], u[1, i], history[hr, i])
        for i in range(D):
            B[m, i] = willingness_of(psi_h[m, i], psi_r[m, i], p, q, b, psi_floor)
        # Alpha: eq (8) on the windows (DS), eq (3) (S), or fixed.
        code = codes[row(codes.shape[0], m)]
        if push:
            for i in range(D):
                B_f = B_window[1, m, i] if W > 1 else 0.0
                for w in range(2, W):
                    B_f += B_window[w, m, i]
                B_f = (B_f + B[m, i]) / W if W > 1 else B[m, i] / W
                a_raw = ds_alpha_of(P_r[m, i], P_h[m, i], B_f)
                a_sum = alpha_window[1, m, i] if W > 1 else 0.0
                for w in range(2, W):
                    a_sum += alpha_window[w, m, i]
                a_sum = a_sum + a_raw if W > 1 else a_raw
                new_B[W - 1, m, i] = B[m, i]
                new_alpha[W - 1, m, i] = a_raw
                if code == _DS_CODE:  # the filtered B is the one reported
                    alpha[m, i] = a_sum / min(count + 1, W)
                    B[m, i] = B_f
        if code == _S_CODE:
            l1_cur = l1_start = 0.0
            for i in range(3):
                l1_cur += abs(Gp[gl, i] - Cp[c, i])
                l1_start += abs(Gp[gl, i] - Tp[cs, i])
            a_s = standard_alpha_of(l1_cur, l1_start, floor_m)
            for i in range(D):
                alpha[m, i] = a_s
        elif code != _DS_CODE:
            for i in range(D):
                alpha[m, i] = 1.0 if code == _AUTONOMOUS_CODE else 0.0
        # Eq (1), then eq (2) from the reference.
        for i in range(D):
            U_out[m, i] = alpha[m, i] * U_r[m, i] + (1.0 - alpha[m, i]) * U_h[m, i]
        integrate_into(Rp, RR, Rg, rf, U_out, m, dt, next_p, next_R, next_g, m)
        if bounded:
            bound_into(Cp, CR, c, max_lead_m, max_lead_rad, next_p, next_R, m)
    return out, next_p, next_R, next_g, new_alpha, new_B


def make_arbiter(mode: Mode | str, config: ArbitrationConfig | None = None) -> Arbiter:
    """The arbiter of a mode (a Mode or its name: DS, S, manual, autonomous)."""
    m = mode if isinstance(mode, Mode) else Mode.parse(mode)
    return Arbiter(m, config or ArbitrationConfig())


def compile_kernels() -> None:
    """Compile (or load from the cache) every compiled function of the package, so that the
    first tick of a session does not wait for it: `dev.sh` runs this at install."""
    from dsteleop.arbitration import allocation, se3

    X = HandState(np.zeros(3), np.eye(3), np.ones(2))
    U = np.zeros(8)
    se3.so3_log(se3.so3_exp(np.zeros(3)))
    se3.diff(X, X)
    se3.integrate(X, U, 0.1)
    se3.saturate(U, np.ones(8))
    policy.advance_reference(X, X, U, 0.1, ArbitrationConfig())
    d = np.zeros((8, 1))
    allocation.standard_alpha(d[:3], d[:3], d[:3], 0.1)
    allocation.expected_allocation(d, d, np.ones(8), 1.0)
    allocation.expected_speed_change(d, np.ones(8), d, d, np.zeros(8), np.ones(8), np.ones(8))
    allocation.willingness(d, d, 2.0, 6.0, 1.0, 0.25)
    allocation.ds_alpha(d, d, d)
    arbiter = make_arbiter(Mode.DS)
    inp = ArbitrationInput(X, X, X, X, X, X, X, 0.1, X_ref=X)
    arbiter.step(arbiter.initial_state(8), inp)
