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
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import allocation, policy
from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.se3 import FING, TRANS, HandState, StateRows, diff_rows, from_rows
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
        history_term: (6 + F,) mean unit direction of previous attempts (eq 6); None if none.
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

    Each window is a tuple of W rows (6 + F, M), oldest first; a tick drops the oldest and
    appends its own, so no window is copied and an earlier state stays valid (rows are
    never written in place).

    Attributes:
        alpha_rows: raw alpha samples (eq 8 on the filtered B, clipped); zeros before the
            first tick (the mean divides by min(count, W) filled samples).
        B_rows: raw willingness samples (eq 7); the window starts full of ones.
        count: ticks seen so far.
        batch: the batch shape (...) of the states it filters, M = prod(batch).
    """

    alpha_rows: tuple[Array, ...]
    B_rows: tuple[Array, ...]
    count: int
    batch: tuple[int, ...]

    @classmethod
    def initial(cls, window: int, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        M = math.prod(batch)
        zeros, ones = np.zeros((dims, M)), np.ones((dims, M))
        zeros.flags.writeable = ones.flags.writeable = False
        return cls((zeros,) * window, (ones,) * window, 0, tuple(batch))

    def push(
        self, B_raw: Array, alpha_of: Callable[[Array], Array]
    ) -> tuple[FilterState, Array, Array]:
        """One more tick: B's window takes B_raw, alpha's window takes `alpha_of(B)` of the
        filtered B (eq 8 on the smoothed willingness). Returns the state, alpha and B."""
        B_rows = (*self.B_rows[1:], B_raw)
        B = sum(B_rows[1:], B_rows[0]) / len(B_rows)
        alpha_rows = (*self.alpha_rows[1:], alpha_of(B))
        alpha = sum(alpha_rows[1:], alpha_rows[0]) / min(self.count + 1, len(alpha_rows))
        return FilterState(alpha_rows, B_rows, self.count + 1, self.batch), alpha, B

    def select(self, keep: NDArray[np.bool_]) -> FilterState:
        """The state of the batch rows `keep` (a mask on a one-axis batch)."""
        return FilterState(
            tuple(r[:, keep] for r in self.alpha_rows),
            tuple(r[:, keep] for r in self.B_rows),
            self.count,
            (int(np.count_nonzero(keep)),),
        )


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
        states = (inp.X_goal, inp.X_human, inp.X_human_prev, inp.X_human_start,
                  inp.X_current, inp.X_prev, inp.X_start)  # fmt: skip
        shapes = {X.batch for X in states}
        batch = shapes.pop() if len(shapes) == 1 else tuple(np.broadcast_shapes(*shapes))
        if inp.X_ref is not None and inp.X_ref.batch not in (batch, ()):
            raise ConfigError(f"X_ref of batch {inp.X_ref.batch} for a tick of batch {batch}")
        F = inp.X_current.n_fingers
        D = 6 + F
        if state.batch != batch or state.B_rows[0].shape[0] != D:
            raise ConfigError(
                f"filter state for batch {state.batch} and {state.B_rows[0].shape[0]} dims, "
                f"tick of batch {batch} and {D} dims"
            )
        M = math.prod(batch)
        v_max = cfg.v_max(F)
        # Every difference of the tick in one pass over 6M pairs, laid out in the rows as
        #   left   [goal  | goal  | human      | robot  | human       | robot  ]
        #   right  [human | robot | human_prev | prev   | human_start | start  ]
        # so that d[:, k] is (goal - agent, agent - its previous, agent - its start) for
        # k = 0, 1, 2 and the agent axis [human, robot] follows.
        goal = inp.X_goal
        left = StateRows.of(
            goal, goal, inp.X_human, inp.X_current, inp.X_human, inp.X_current, batch=batch
        )
        right = StateRows.of(
            inp.X_human, inp.X_current, inp.X_human_prev, inp.X_prev, inp.X_human_start,
            inp.X_start, batch=batch,
        )  # fmt: skip
        d = diff_rows(left, right).reshape(D, 3, 2, M)
        d_goal, d_prev, d_start = d[:, 0], d[:, 1], d[:, 2]
        G, C, Cs = left.part(0, M), left.part(3, M), right.part(5, M)
        U_h = policy.human_action(d_prev[:, 0], inp.dt, cfg)
        U_r = policy.robot_action(d_goal[:, 1], cfg)
        d_goal_start = np.zeros((D, 1, M))
        d_goal_start[TRANS, 0] = G.p - Cs.p
        d_goal_start[FING, 0] = G.g - Cs.g
        P = allocation.expected_allocation(d_goal, d_goal_start, cfg.alloc_floor(F), cfg.kappa)
        U = np.stack((U_h, U_r), 1)
        psi = allocation.expected_speed_change(
            U, v_max, d_prev, d_start, inp.history_term, cfg.still_step(F, inp.dt),
            cfg.still_offset(F),
        )  # fmt: skip
        psi_h, psi_r = psi[:, 0], psi[:, 1]
        B = allocation.willingness(psi_h, psi_r, cfg.p, cfg.q, cfg.b, cfg.psi_robot_floor)
        P_h, P_r = P[:, 0], P[:, 1]

        def ds(B: Array) -> tuple[FilterState, Array, Array]:
            return state.push(B, lambda B_f: allocation.ds_alpha(P_r, P_h, B_f))

        def standard() -> Array:
            a = allocation.standard_alpha(G.p, C.p, Cs.p, cfg.alloc_floor_m)
            return np.broadcast_to(a, (D, M))

        if rows is None:
            if self.mode is Mode.DS:
                state, alpha, B = ds(B)
            elif self.mode is Mode.S:
                alpha = standard()
            else:
                alpha = np.full((D, M), 1.0 if self.mode is Mode.AUTONOMOUS else 0.0)
        else:
            if rows.codes.shape != (M,):
                raise ConfigError(f"modes for {rows.codes.shape} rows, tick of batch {batch}")
            alpha = np.empty((D, M))
            for mode, where in rows.groups():
                if mode is Mode.DS:
                    state, a_ds, B_ds = ds(B)
                    alpha[:, where], B = a_ds[:, where], np.where(where, B_ds, B)
                elif mode is Mode.S:
                    alpha[:, where] = standard()[:, where]
                else:
                    alpha[:, where] = 1.0 if mode is Mode.AUTONOMOUS else 0.0
        U_out = alpha * U_r + (1.0 - alpha) * U_h
        X_ref = C if inp.X_ref is None else StateRows.of(inp.X_ref, batch=batch)
        X_next = policy.advance_rows(X_ref, C, U_out, inp.dt, cfg)

        def out(x: Array) -> Array:
            return from_rows(x, batch)

        return state, ArbitrationStep(
            alpha=out(alpha),
            P_human=out(P_h),
            P_robot=out(P_r),
            B=out(B),
            psi_human=out(psi_h),
            psi_robot=out(psi_r),
            U_human=out(U_h),
            U_robot=out(U_r),
            U_out=out(U_out),
            X_next=X_next.state(batch),
        )


def make_arbiter(mode: Mode | str, config: ArbitrationConfig | None = None) -> Arbiter:
    """The arbiter of a mode (a Mode or its name: DS, S, manual, autonomous)."""
    m = mode if isinstance(mode, Mode) else Mode.parse(mode)
    return Arbiter(m, config or ArbitrationConfig())
