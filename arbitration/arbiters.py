"""The arbiter: one tick of eq (1)-(8) for any mode, on a batch of any size.

One tick, for every dimension i of 6 + F (the maths of each line is stated in `policy.py`,
`allocation.py` and the modes' modules):

    U_robot = sat(K_r * diff(X_goal, X_current))                  goal-seeking policy
    U_human = sat(diff(X_human, X_human_prev) / dt)                the hand's own motion
    P(H), P(R), psi_human, psi_robot, B                            eq (4)-(7)
    alpha_i = the row's mode's rule (`arbitration/modes/`)
    U_out   = alpha * U_robot + (1 - alpha) * U_human              (1)
    X_next  = advance_reference(X_ref, X_current, U_out, dt)       (2)

It runs in three passes: the shared part (`_shared`, one compiled kernel over every row: the
actions, eq (4)-(7) and eq (3)'s distances, `modes.Quantities`), each mode's alpha rule on
its own rows, then eq (1)-(2) (`_finish`, one compiled kernel). The kernels take the tick's
states as one named batch (`TickStates`). Every mode gets P(H), P(R), psi and B, so a viewer
or a recorder sees the same quantities whatever the mode; a caller that reads only the
actions (the simulation study) may ask for them only where a mode's rule reads them
(`step(..., every_quantity=False)`: NaN elsewhere, the actions and states unchanged). The
modes are plug-ins (`arbitration/modes/`): `manual` alpha = 0; `autonomous` alpha = 1; `S`
eq (3); `scalar` eq (3) with a cap and a scale; `DS` eq (8) on moving windows of B_i and
alpha_i (its own filter state).

What "X_human" eq (4)-(6) read is `ArbitrationConfig.human_reference` (docs/METHOD.md §2):
"hand" (the default) reads the hand's mapped pose itself; "leaky" reads the hand's reference
X_ref, a pose whose lead over the robot decays with time constant tau = `human_leak_s`:

    X_ref_k = X_current_k (+) exp(-dt / tau) * ((X_ref_{k-1} (+) U_human dt) (-) X_current_k)

((+) and (-) are `se3.integrate` and `se3.diff`: positions and openness add, rotations go
through the rotation vector of their difference), restarted at the robot's segment start
(X_ref_{-1} = X_start, which is also its start for eq (6)). It is per-row state of the
arbiter (`FilterState.reference`), restarted with the modes' state at each new segment.
U_human is the hand's own motion either way.

All arrays may carry a leading batch shape (the states broadcast against each other; the
filter state is made for the tick's batch shape); the loop runs a batch of one, the
simulation study thousands of trajectories.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import policy
from dsteleop.arbitration.allocation import (
    allocation_linear,
    allocation_rotation,
    speed_change_of,
    unit_directions_into,
    willingness_of,
)
from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.jit import as_input, kernel
from dsteleop.arbitration.modes import Mode, Quantities, registered
from dsteleop.arbitration.policy import bound_into, human_action_into, robot_action_into
from dsteleop.arbitration.se3 import (
    HandState,
    batch_of,
    diff,
    diff_into,
    integrate,
    integrate_into,
    row,
    saturate,
    state_input,
)
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
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
        confidence: (6 + F,) or (..., 6 + F) the robot's confidence c_i in [0, 1] in each
            dimension of X_goal (`belief.GoalBelief.confidence`; docs/METHOD.md §10), which
            the modes that read it (`DSC`) temper with; None: 1 everywhere (a goal it is
            told, trusted fully).
        confidence_joint: a float or (...,) the confidence c_joint in [0, 1] in the whole
            goal at once (the confidence-scaled scalar baseline reads it); None: 1.
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
    confidence: Array | None = None
    confidence_joint: Array | float | None = None


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
    """The filter state of a batch: each stateful mode's own state for the batch's rows.

    Attributes:
        batch: the batch shape (...) of the states it filters, M = prod(batch).
        dims: 6 + F, the dimensions it filters.
        own: (mode name, its state) for every registered mode with a state of its own (DS's
            moving windows, `modes.ds.Windows`); a mode registered later starts from its
            initial state on its first tick.
        reference: the hand's leaky reference X_ref of the last tick, of the batch's shape
            (`human_reference="leaky"`, module docstring); None at a segment's start (and
            always under "hand").
    """

    batch: tuple[int, ...]
    dims: int
    own: tuple[tuple[str, Any], ...] = ()
    reference: HandState | None = None

    def of(self, mode: Mode | str) -> Any:
        """The own state of `mode` (None if it has none yet)."""
        for name, st in self.own:
            if name == mode:
                return st
        return None

    @property
    def count(self) -> int:
        """Ticks DS has stepped its windows (0 before its first)."""
        ds = self.of(Mode.DS)
        return 0 if ds is None else int(ds.count)

    @property
    def alpha_window(self) -> Array:
        """DS's alpha window (W, M', 6 + F), oldest tick first (`modes.ds.Windows`: M' = M,
        or in a batch that mixes modes DS's own rows, `Windows.rows`)."""
        return self.of(Mode.DS).alpha_window

    @property
    def B_window(self) -> Array:
        """DS's B window (W, M', 6 + F), oldest tick first."""
        return self.of(Mode.DS).B_window

    @property
    def alpha_rows(self) -> tuple[Array, ...]:
        """DS's alpha window's W rows (M', 6 + F), oldest first."""
        return tuple(self.alpha_window)

    @property
    def B_rows(self) -> tuple[Array, ...]:
        """DS's B window's W rows (M', 6 + F), oldest first."""
        return tuple(self.B_window)

    def select(self, keep: NDArray[np.bool_]) -> FilterState:
        """The state of the batch rows `keep` (a mask on a one-axis batch)."""
        own = tuple((name, st.select(keep)) for name, st in self.own)
        ref = None if self.reference is None else self.reference.take(keep)
        return FilterState((int(np.count_nonzero(keep)),), self.dims, own, ref)


@dataclass(frozen=True)
class RowModes:
    """The mode of every row of a batch that mixes modes (flattened batch order).

    Attributes:
        codes: (M,) index of each row's mode in `modes`.
        modes: the modes the codes index.
    """

    codes: NDArray[np.int8]
    modes: tuple[Mode, ...] = field(default_factory=registered)

    @classmethod
    def of(cls, modes: list[Mode] | tuple[Mode, ...]) -> RowModes:
        table = tuple(dict.fromkeys(modes))
        return cls(np.array([table.index(m) for m in modes], dtype=np.int8), table)

    def groups(self) -> list[tuple[Mode, NDArray[np.bool_]]]:
        """(mode, mask of its rows) for each mode present."""
        return [(m, self.codes == i) for i, m in enumerate(self.modes) if (self.codes == i).any()]

    @functools.cached_property
    def index(self) -> tuple[tuple[Mode, NDArray[np.intp]], ...]:
        """(mode, indices of its rows) for each mode present (computed once: a study steps
        the same rows many ticks; read-only: a mode's state may keep them)."""
        out = tuple((m, np.flatnonzero(mask)) for m, mask in self.groups())
        for _, rows in out:
            rows.flags.writeable = False
        return out

    @functools.cached_property
    def reads_allocation(self) -> Array:
        """(M,) 1.0 where the row's mode reads eq (4)-(7) (`ModeSpec.reads_allocation`), else
        0.0: the rows `Arbiter.step(..., every_quantity=False)` computes them for."""
        reads = np.array([float(m.spec.reads_allocation) for m in self.modes])
        out = reads[self.codes] if len(self.modes) else np.zeros(self.codes.shape)
        out.flags.writeable = False
        return np.asarray(out, dtype=np.float64)

    def select(self, keep: NDArray[np.bool_]) -> RowModes:
        """The modes of the rows `keep`."""
        return RowModes(self.codes[keep], self.modes)


class StateRows(NamedTuple):
    """One state's arrays for the kernels: M rows, or one shared by every row."""

    position: Array
    rotation: Array
    openness: Array


class TickStates(NamedTuple):
    """The tick's states, as the compiled kernels take them (one named batch): `reading` and
    `reading_start` are what eq (4)-(6) read as the human's state and its start (the hand's
    own arrays under `human_reference="hand"`, the leaky reference's under "leaky")."""

    human: StateRows
    human_prev: StateRows
    human_start: StateRows
    current: StateRows
    prev: StateRows
    start: StateRows
    goal: StateRows
    ref: StateRows
    reading: StateRows
    reading_start: StateRows


#: The kernels' indices of the states of `TickStates` (a plain tuple reaches them: numba
#: dispatches a named tuple several times slower than the same tuple).
_HUMAN, _HUMAN_PREV, _HUMAN_START, _CURRENT, _PREV, _START, _GOAL, _REF = range(8)
_READING, _READING_START = 8, 9
assert TickStates._fields.index("ref") == _REF and TickStates._fields.index("goal") == _GOAL
assert TickStates._fields[_READING:] == ("reading", "reading_start")


@dataclass(frozen=True)
class Arbiter:
    """One mode's arbitration: `state, step = arbiter.step(state, inp)`.

    Attributes:
        mode: the mode.
        config: the hyper-parameters.
    """

    mode: Mode = field(default_factory=lambda: Mode.DS)
    config: ArbitrationConfig = field(default_factory=ArbitrationConfig)

    def initial_state(self, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        """A fresh filter state (DS: windows empty, B = 1): at start and at each new segment."""
        M = math.prod(batch)
        own = tuple(
            (m.value, m.spec.initial_state(self.config, dims, M))
            for m in registered()
            if m.spec.initial_state is not None
        )
        return FilterState(tuple(batch), dims, own)

    def step(
        self,
        state: FilterState,
        inp: ArbitrationInput,
        rows: RowModes | None = None,
        every_quantity: bool = True,
    ) -> tuple[FilterState, ArbitrationStep]:
        """One tick (module docstring); a mode's own filter state changes only when it has
        rows in the tick.

        Args:
            state: the filter state (`initial_state`) for the tick's batch.
            inp: the tick's states.
            rows: a mode per batch row (a batch that mixes modes, as the simulation study
                steps every mode of a trajectory at once); None: every row in `mode`.
            every_quantity: compute eq (4)-(7) (P_human, P_robot, psi, B) for every row;
                False: only for the rows of modes whose rule reads them
                (`ModeSpec.reads_allocation`), NaN in the others (the actions, alpha and
                X_next are the same either way; the study, which reads only those, saves
                the work).

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
        if state.batch != batch or state.dims != D:
            raise ConfigError(
                f"filter state for batch {state.batch} and {state.dims} dims, "
                f"tick of batch {batch} and {D} dims"
            )
        M = math.prod(batch)
        if rows is None:
            groups = [(self.mode, _all_rows(M))]
            wanted = _EVERY if every_quantity or self.mode.spec.reads_allocation else _NONE
        else:
            if rows.codes.shape != (M,):
                raise ConfigError(f"modes for {rows.codes.shape} rows, tick of batch {batch}")
            groups = list(rows.index)
            wanted = _EVERY if every_quantity else rows.reads_allocation
        dt = float(inp.dt)
        X_ref = inp.X_current if inp.X_ref is None else inp.X_ref
        reading, reading_start, reference = inp.X_human, inp.X_human_start, None
        if cfg.human_reference == "leaky":
            reference = leaky_reference(state.reference, inp, cfg)
            reading, reading_start = reference, inp.X_start
        # The named batch, as the plain tuple the kernels take (fields of `TickStates`).
        s = tuple(state_input(X, batch) for X in (*states, X_ref, reading, reading_start))
        history = np.zeros(D) if inp.history_term is None else inp.history_term
        out, l1 = _shared(
            s, as_input(history, batch, 1), wanted, _per_dim_params(cfg, F, dt),
            dt, float(cfg.kappa), float(cfg.p), float(cfg.q), float(cfg.b),
            float(cfg.psi_robot_floor), float(cfg.alloc_floor_m), M,
        )  # fmt: skip
        q = Quantities(
            alpha=out[0], P_human=out[1], P_robot=out[2], B=out[3], psi_human=out[4],
            psi_robot=out[5], U_human=out[6], U_robot=out[7], l1_goal_current_m=l1[0],
            l1_goal_start_m=l1[1], confidence=_confidence_rows(inp.confidence, batch, D),
            confidence_joint=_confidence_rows(inp.confidence_joint, batch, 0),
        )  # fmt: skip
        own = dict(state.own)
        for mode, idx in groups:
            spec, name = mode.spec, mode.value
            params = None if spec.params is None else cfg.params_of(name)
            if spec.initial_state is None:
                spec.alpha(params, q, idx, None)
                continue
            st = own.get(name)
            if st is None:
                st = spec.initial_state(cfg, D, M)
            own[name] = spec.alpha(params, q, idx, st)
        if (
            reference is not None
            or len(own) != len(state.own)
            or any(own[n] is not st for n, st in state.own)
        ):
            state = FilterState(state.batch, D, tuple(own.items()), reference)
        (Cp, CR, _), (Rp, RR, Rg) = s[_CURRENT], s[_REF]
        p, R, g = _finish(
            Cp, CR, Rp, RR, Rg, out, dt,
            float(cfg.max_lead_m), float(cfg.max_lead_rad),
            policy.bound_needed(inp.X_ref is not None, dt, cfg), M,
        )  # fmt: skip
        shape = (*batch, D)
        arrays_out: dict[str, Any] = {n: out[k].reshape(shape) for k, n in enumerate(STEP_ARRAYS)}
        X_next = HandState(p.reshape(*batch, 3), R.reshape(*batch, 3, 3), g.reshape(*batch, F))
        return state, ArbitrationStep(**arrays_out, X_next=X_next)


def leaky_reference(
    previous: HandState | None, inp: ArbitrationInput, cfg: ArbitrationConfig
) -> HandState:
    """The hand's leaky reference X_ref of this tick (module docstring), from the last tick's
    (`previous`; None at a segment's start: it restarts at X_start), carried by the hand's
    motion U_human and its lead over X_current decayed by exp(-dt / human_leak_s).

    Returns it with the tick's batch shape (what `FilterState.reference` keeps)."""
    dt = float(inp.dt)
    F = inp.X_current.n_fingers
    last = inp.X_start if previous is None else previous
    U_human = saturate(diff(inp.X_human, inp.X_human_prev) / dt, cfg.v_max(F))
    carried = integrate(last, U_human, dt)
    lead = diff(carried, inp.X_current) * math.exp(-dt / cfg.human_leak_s)
    return integrate(inp.X_current, lead, 1.0)


def _confidence_rows(c: Array | float | None, batch: tuple[int, ...], D: int) -> Array:
    """The tick's confidence as (M, D) (D = 0: the joint one, (M,)), read-only; None: ones.

    Raises:
        ConfigError: it does not broadcast to the tick's batch, or a value is not in [0, 1].
    """
    M = math.prod(batch)
    tail = (D,) if D else ()
    if c is None:
        return _ones(M, D)
    a = np.asarray(c, dtype=np.float64)
    try:  # a confidence of the tick's shape (the study's, every tick) is only reshaped
        if a.shape != (*batch, *tail):
            a = np.broadcast_to(a, (*batch, *tail))
        a = a.reshape(M, *tail)  # a new array object (a view where it can): never the caller's
    except ValueError:
        what = "confidence" if D else "confidence_joint"
        raise ConfigError(f"{what} of shape {a.shape} for a tick of batch {batch}") from None
    # Two reductions, no temporaries (checked every tick); NaN fails too (min/max keep it).
    if a.size and not (a.min() >= 0.0 and a.max() <= 1.0):
        what = "confidence" if D else "confidence_joint"
        raise ConfigError(f"{what} must be in [0, 1]")
    a.flags.writeable = False
    return a


@functools.lru_cache(maxsize=16)
def _ones(M: int, D: int) -> Array:
    """(M, D) ones (D = 0: (M,)), read-only (cached: the confidence of a told goal)."""
    out = np.ones((M, D) if D else (M,))
    out.flags.writeable = False
    return out


#: Rows of the kernel's scratch array of differences.
_GOAL_H, _GOAL_R, _PREV_H, _PREV_R, _START_H, _START_R = range(6)
#: The row of `U_out` in the kernels' output (the STEP_ARRAYS before it are the quantities).
_U_OUT = 8
assert STEP_ARRAYS.index("U_out") == _U_OUT and STEP_ARRAYS[:_U_OUT] == (
    "alpha", "P_human", "P_robot", "B", "psi_human", "psi_robot", "U_human", "U_robot",
)  # fmt: skip


#: `_shared`'s `wanted` for every row and for none (one row, shared by every row).
_EVERY, _NONE = np.ones(1), np.zeros(1)
_EVERY.flags.writeable = _NONE.flags.writeable = False


@functools.lru_cache(maxsize=16)
def _all_rows(M: int) -> NDArray[np.intp]:
    """Every row of a batch of M, as the alpha rules take rows (read-only, cached)."""
    rows = np.arange(M, dtype=np.intp)
    rows.flags.writeable = False
    return rows


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
def _shared(
    s: Any, history: Array, wanted: Array, params: Array, dt: float, kappa: float, p: float,
    q: float, b: float, psi_floor: float, floor_m: float, M: int,
) -> tuple[Array, Array]:  # fmt: skip
    """The shared part of one tick of M rows (module docstring); each state of `s` (a
    `TickStates` as a plain tuple) has M rows or one (shared). Eq (4)-(7) are computed for
    the rows where `wanted` (M rows or one) is non-zero, NaN elsewhere.

    Returns the STEP_ARRAYS (9, M, 6 + F) with alpha and U_out left for the modes and
    `_finish`, and eq (3)'s L1 distances (2, M): goal-current and the floored goal-start.
    """
    Hp, HR, Hg = s[_HUMAN][0], s[_HUMAN][1], s[_HUMAN][2]
    Pp, PR, Pg = s[_HUMAN_PREV][0], s[_HUMAN_PREV][1], s[_HUMAN_PREV][2]
    Cp, CR, Cg = s[_CURRENT][0], s[_CURRENT][1], s[_CURRENT][2]
    Qp, QR, Qg = s[_PREV][0], s[_PREV][1], s[_PREV][2]
    Tp, TR, Tg = s[_START][0], s[_START][1], s[_START][2]
    Gp, GR, Gg = s[_GOAL][0], s[_GOAL][1], s[_GOAL][2]
    Ep, ER, Eg = s[_READING][0], s[_READING][1], s[_READING][2]
    Op, OR, Og = s[_READING_START][0], s[_READING_START][1], s[_READING_START][2]
    F = Cg.shape[1]
    D = 6 + F
    gains, v_max, floor, still_step, still_offset = (
        params[0],
        params[1],
        params[2],
        params[3],
        params[4],
    )
    out = np.empty((9, M, D))
    P_h, P_r, B, psi_h, psi_r, U_h, U_r = (
        out[1],
        out[2],
        out[3],
        out[4],
        out[5],
        out[6],
        out[7],
    )
    l1 = np.empty((2, M))
    # Rows of the scratch arrays: the six differences (to the goal, to the previous state,
    # to the start, per agent) and the two unit directions of eq (6).
    d, u = np.empty((6, D)), np.empty((2, D))
    for m in range(M):
        h, hp = row(Hp.shape[0], m), row(Pp.shape[0], m)
        e, es = row(Ep.shape[0], m), row(Op.shape[0], m)
        c, cp, cs = row(Cp.shape[0], m), row(Qp.shape[0], m), row(Tp.shape[0], m)
        gl, hr = row(Gp.shape[0], m), row(history.shape[0], m)
        diff_into(Gp, GR, Gg, gl, Cp, CR, Cg, c, d, _GOAL_R)
        diff_into(Hp, HR, Hg, h, Pp, PR, Pg, hp, d, _PREV_H)
        # The two actions (policy.py).
        human_action_into(d, _PREV_H, dt, v_max, U_h, m)
        robot_action_into(d, _GOAL_R, gains, v_max, U_r, m)
        # Eq (3)'s distances, the robot's position (S and the scalar baseline read them).
        l1_cur = l1_start = 0.0
        for i in range(3):
            l1_cur += abs(Gp[gl, i] - Cp[c, i])
            l1_start += abs(Gp[gl, i] - Tp[cs, i])
        l1[0, m] = l1_cur
        l1[1, m] = max(l1_start, floor_m)
        if wanted[row(wanted.shape[0], m)] == 0.0:
            for i in range(D):
                P_h[m, i] = P_r[m, i] = B[m, i] = psi_h[m, i] = psi_r[m, i] = np.nan
            continue
        diff_into(Gp, GR, Gg, gl, Ep, ER, Eg, e, d, _GOAL_H)
        diff_into(Cp, CR, Cg, c, Qp, QR, Qg, cp, d, _PREV_R)
        diff_into(Ep, ER, Eg, e, Op, OR, Og, es, d, _START_H)
        diff_into(Cp, CR, Cg, c, Tp, TR, Tg, cs, d, _START_R)
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
    return out, l1


@kernel
def _finish(
    Cp: Array, CR: Array, Rp: Array, RR: Array, Rg: Array, out: Array, dt: float,
    max_lead_m: float, max_lead_rad: float, bounded: bool, M: int,
) -> tuple[Array, Array, Array]:  # fmt: skip
    """Eq (1), then eq (2) from the reference (Rp, RR, Rg), bounded about the current state
    (Cp, CR), for M rows: writes U_out into `out` and returns X_next (position, rotation,
    openness). It reads only these two states (fewer arrays for numba to dispatch on)."""
    F = Rg.shape[1]
    D = 6 + F
    alpha, U_h, U_r, U_out = out[0], out[6], out[7], out[_U_OUT]
    next_p, next_R, next_g = np.empty((M, 3)), np.empty((M, 3, 3)), np.empty((M, F))
    for m in range(M):
        c, rf = row(Cp.shape[0], m), row(Rp.shape[0], m)
        for i in range(D):
            U_out[m, i] = alpha[m, i] * U_r[m, i] + (1.0 - alpha[m, i]) * U_h[m, i]
        integrate_into(Rp, RR, Rg, rf, U_out, m, dt, next_p, next_R, next_g, m)
        if bounded:
            bound_into(Cp, CR, c, max_lead_m, max_lead_rad, next_p, next_R, m)
    return next_p, next_R, next_g


def make_arbiter(mode: Mode | str, config: ArbitrationConfig | None = None) -> Arbiter:
    """The arbiter of a mode (a Mode, or its name: DS, S, manual, autonomous, scalar, ...;
    a Mode is taken as it is, never parsed again)."""
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
    inp = ArbitrationInput(
        X_human=X, X_human_prev=X, X_human_start=X, X_current=X, X_prev=X, X_start=X,
        X_goal=X, dt=0.1, X_ref=X,
    )  # fmt: skip
    arbiter.step(arbiter.initial_state(8), inp)
    # Every mode's rule, through a mixed batch of two rows.
    X2 = se3.stack([X, X])
    inp2 = ArbitrationInput(
        X_human=X2, X_human_prev=X2, X_human_start=X2, X_current=X2, X_prev=X2, X_start=X2,
        X_goal=X2, dt=0.1,
    )  # fmt: skip
    state = arbiter.initial_state(8, (2,))
    for mode in registered():
        state, _ = arbiter.step(state, inp2, RowModes.of([mode, Mode.DS]))
