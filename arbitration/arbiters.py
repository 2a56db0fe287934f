"""The arbiters: blend the operator's and the robot's actions per dimension, eq (1)-(8).

One tick, for every dimension i of 6 + F (DESIGN.md §2-3):

    U_robot = sat(K_r * diff(X_goal, X_current))                  goal-seeking policy
    U_human = sat(diff(X_human, X_human_prev) / dt)                the hand's own motion
    alpha_i = mode-specific (below)
    U_out   = alpha * U_robot + (1 - alpha) * U_human              (1)
    X_next  = integrate(X_current, U_out, dt)                      (2)

Modes: `manual` alpha = 0; `autonomous` alpha = 1; `S` eq (3), one alpha for all dims;
`DS` eq (8), with a moving-average window over B_i and alpha_i (B's window starts full of
ones: B starts at 1). Every mode also computes P(H), P(R), psi and B, so a viewer or a
recorder sees the same quantities whatever the mode.

All arrays may carry a leading batch axis; the DS filter state then has the same batch.

Two implementations of the same tick: a single state (no batch axis) runs on Python floats
(`scalar.py`, ~47 us a step, for the 30 Hz loop), a batch runs component-major numpy (`batched.py`,
for thousands of trajectories). Both return the same numbers (to 1e-9) and the same types.
"""

from __future__ import annotations

import enum
import functools
import math
import struct
from dataclasses import dataclass, field
from typing import ClassVar, Protocol, TypeVar, cast

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import batched, scalar
from dsteleop.arbitration.allocation import standard_alpha
from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.se3 import HandState

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
        raise ValueError(f"unknown mode {text!r} (choose from {names})")


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
        history_term: (6 + F,) mean unit direction of previous attempts (eq 6); zeros if none.
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


#: One sample of a moving window, (..., D): an array, or on the single-state path a tuple of
#: floats (that path computes on Python floats, so its samples stay floats between ticks).
Row = batched.Row


@dataclass(frozen=True)
class FilterState:
    """Moving windows of the DS arbiter: the last W raw alpha and B samples (dims D).

    The windows are rings of W rows in slot order, each (..., D) for a batch shape (...). A
    tick replaces one row and shares the other W - 1 with the state it came from, so stepping
    copies no window and every earlier state stays valid (rows are never written in place).
    `alpha_buf` and `B_buf` stack the rows as (..., W, D) arrays.

    Attributes:
        alpha_rows: W raw alpha samples (eq 8, clipped, before the window mean).
        B_rows: W raw willingness samples (eq 7); the window starts full of ones.
        count: alpha samples seen so far (the alpha mean divides by min(count, W)).
    """

    alpha_rows: tuple[Row, ...]
    B_rows: tuple[Row, ...]
    count: int = 0

    @classmethod
    def initial(cls, window: int, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        if not batch:
            return cls(((0.0,) * dims,) * window, ((1.0,) * dims,) * window, 0)
        zeros, ones = np.zeros((*batch, dims)), np.ones((*batch, dims))
        zeros.flags.writeable = ones.flags.writeable = False
        return cls((zeros,) * window, (ones,) * window, 0)

    @classmethod
    def from_buffers(cls, alpha_buf: Array, B_buf: Array, count: int) -> FilterState:
        """A state from (..., W, D) windows (copied)."""
        W = B_buf.shape[-2]
        return cls(
            tuple(alpha_buf[..., w, :].copy() for w in range(W)),
            tuple(B_buf[..., w, :].copy() for w in range(W)),
            count,
        )

    @property
    def alpha_buf(self) -> Array:
        """(..., W, D): the alpha window, rows in slot order."""
        return np.stack([np.asarray(r, dtype=np.float64) for r in self.alpha_rows], axis=-2)

    @property
    def B_buf(self) -> Array:
        """(..., W, D): the willingness window, rows in slot order."""
        return np.stack([np.asarray(r, dtype=np.float64) for r in self.B_rows], axis=-2)

    @property
    def shape(self) -> tuple[int, ...]:
        """(..., D): the batch shape and the number of dims."""
        return np.shape(self.B_rows[0])

    def select(self, index: NDArray[np.bool_] | NDArray[np.intp]) -> FilterState:
        """The state of the batch rows `index` (a boolean mask or indices on the first axis)."""
        return FilterState(
            tuple(np.asarray(r)[index] for r in self.alpha_rows),
            tuple(np.asarray(r)[index] for r in self.B_rows),
            self.count,
        )


@functools.lru_cache(maxsize=64)
def _vectors(cfg: ArbitrationConfig, n_fingers: int) -> tuple[Array, Array, Array]:
    """Per-dimension gains, velocity limits and eps (cached: built once per config)."""
    return cfg.gains(n_fingers), cfg.v_max(n_fingers), cfg.eps(n_fingers)


def _states(inp: ArbitrationInput) -> tuple[HandState, ...]:
    return (
        inp.X_human,
        inp.X_human_prev,
        inp.X_human_start,
        inp.X_current,
        inp.X_prev,
        inp.X_start,
        inp.X_goal,
    )


def _single(inp: ArbitrationInput, state: FilterState) -> list[scalar.State] | None:
    """The seven states as Python floats for the scalar path, or None when the tick is not a
    single one (a batch axis anywhere, or shapes that only broadcasting would reconcile)."""
    shape = inp.X_current.openness.shape
    if len(shape) != 1:
        return None
    D = 6 + shape[0]
    row = state.B_rows[0]
    if len(row) != D or (isinstance(row, np.ndarray) and row.ndim != 1):
        return None
    if inp.history_term is not None and inp.history_term.shape != (D,):
        return None
    states = []
    for s in _states(inp):
        p, R, g = s.position, s.rotation, s.openness
        if R.ndim != 2 or p.ndim != 1 or g.shape != shape:
            return None
        states.append((p.tolist(), R.tolist(), g.tolist()))
    return states


@functools.lru_cache(maxsize=64)
def _scalar_constants(cfg: ArbitrationConfig) -> scalar.Constants:
    """Constants of the scalar tick (cached: built once per config)."""
    zm = (cfg.p - 1.0) / (cfg.q + 1.0)
    return scalar.Constants(
        kt=cfg.k_trans_per_s,
        kr=cfg.k_rot_per_s,
        kf=cfg.k_finger_per_s,
        vt=cfg.v_max_mps,
        vr=cfg.w_max_radps,
        vf=cfg.g_max_per_s,
        et=cfg.eps_trans_m,
        er=cfg.eps_rot_rad,
        ef=cfg.eps_finger,
        kappa=cfg.kappa,
        pm1=cfg.p - 1.0,
        nq1=-(cfg.q + 1.0),
        scale=cfg.b * (cfg.q - 1.0) / cfg.p,
        k0=math.exp((cfg.p + cfg.q) * math.log1p(zm) - (cfg.p - 1.0) * math.log(zm)),
        floor=cfg.psi_robot_floor,
        eps_m=cfg.eps_trans_m,
    )


def _float_rows(rows: tuple[Row, ...]) -> tuple[tuple[float, ...], ...]:
    """Window rows in the scalar path's form, tuples of floats (array rows are converted)."""
    if type(rows[0]) is tuple:
        return cast(tuple[tuple[float, ...], ...], rows)
    return tuple(tuple(np.asarray(r, dtype=np.float64).tolist()) for r in rows)


def _scalar_step(
    mode: Mode,
    c: scalar.Constants,
    state: FilterState,
    inp: ArbitrationInput,
    states: list[scalar.State],
) -> tuple[FilterState, ArbitrationStep]:
    """One unbatched tick of any mode on Python floats (`scalar.py`); same numbers."""
    hist = None if inp.history_term is None else inp.history_term.tolist()
    U_h, U_r, P_h, P_r, psi_h, psi_r, B_raw = scalar.kernel(states, c, inp.dt, hist)
    B = B_raw
    D = len(U_h)
    if mode is Mode.DS:
        rows = _float_rows(state.alpha_rows), _float_rows(state.B_rows)
        alpha, B, alpha_rows, B_rows = scalar.ds_filter(P_r, P_h, B_raw, *rows, state.count)
        state = _new(FilterState, alpha_rows=alpha_rows, B_rows=B_rows, count=state.count + 1)
    elif mode is Mode.S:
        alpha = [scalar.standard_alpha(states[6][0], states[3][0], states[5][0], c.eps_m)] * D
    else:
        alpha = [1.0 if mode is Mode.AUTONOMOUS else 0.0] * D
    U_out, (p, R, g) = scalar.finish(states[3], U_h, U_r, alpha, inp.dt)
    # One conversion to numpy for every output, in the order of STEP_ARRAYS then X_next:
    # struct packs the floats straight into the array's memory (~2x faster than np.fromiter;
    # star-unpacking ~1.6x faster than itertools.chain); the arrays are views of it.
    buf = np.empty(10 * D + 6)
    # (numpy 1.26's stubs do not declare the buffer protocol, hence the ignore)
    _packer(D).pack_into(
        buf,  # type: ignore[arg-type]
        0, *alpha, *P_h, *P_r, *B, *psi_h, *psi_r, *U_h, *U_r,
        *U_out, *p, *R[0], *R[1], *R[2], *g,
    )  # fmt: skip
    i = 9 * D + 12
    X_next = _new(
        HandState,
        position=buf[9 * D : 9 * D + 3],
        rotation=buf[9 * D + 3 : i].reshape(3, 3),
        openness=buf[i:],
    )
    result = _new(ArbitrationStep, X_next=X_next)
    result.__dict__.update(zip(STEP_ARRAYS, buf[: 9 * D].reshape(9, D)))
    return state, result


@functools.lru_cache(maxsize=16)
def _packer(D: int) -> struct.Struct:
    """Native doubles for the nine (D,) outputs of a tick and the next state (12 + D - 6)."""
    return struct.Struct(f"{10 * D + 6}d")


_T = TypeVar("_T")


def _new(cls: type[_T], **fields: object) -> _T:
    """An instance of a frozen dataclass without its generated `__init__`.

    The generated `__init__` of a frozen dataclass sets each field through
    `object.__setattr__`, ~0.3 us per field; a 30 Hz tick builds three such objects. Only for
    our own classes that have no `__post_init__` (HandState, FilterState, ArbitrationStep).
    """
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


def _tick(cfg: ArbitrationConfig, inp: ArbitrationInput) -> batched.Tick:
    """Mode-independent quantities of a batched tick (`batched.py`)."""
    gains, v_max, eps = _vectors(cfg, inp.X_current.n_fingers)
    return batched.kernel(
        _states(inp),
        inp.dt,
        inp.history_term,
        gains,
        v_max,
        eps,
        cfg.kappa,
        cfg.p,
        cfg.q,
        cfg.b,
        cfg.psi_robot_floor,
    )


def _batched_step(t: batched.Tick, alpha: Array, B: Array, dt: float) -> ArbitrationStep:
    """Eq (1)-(2) and the result of a batched tick; alpha and B are (D, N), like the tick."""
    U_out, X_next = batched.finish(t, alpha, dt)
    shape = U_out.shape

    def out(x: Array) -> Array:
        return x.reshape(shape)

    return ArbitrationStep(
        alpha=out(alpha.T),
        P_human=out(t.P[:, 0].T),
        P_robot=out(t.P[:, 1].T),
        B=out(B.T),
        psi_human=out(t.psi[:, 0].T),
        psi_robot=out(t.psi[:, 1].T),
        U_human=out(t.U[:, 0].T),
        U_robot=out(t.U[:, 1].T),
        U_out=U_out,
        X_next=X_next,
    )


class Arbiter(Protocol):
    """One interface for every mode: `state, result = arbiter.step(state, inp)`."""

    mode: Mode
    config: ArbitrationConfig

    def initial_state(self, dims: int, batch: tuple[int, ...] = ()) -> FilterState: ...

    def step(
        self, state: FilterState, inp: ArbitrationInput
    ) -> tuple[FilterState, ArbitrationStep]: ...


@dataclass(frozen=True)
class _Base:
    config: ArbitrationConfig = field(default_factory=ArbitrationConfig)
    mode: ClassVar[Mode]

    def initial_state(self, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        return FilterState.initial(self.config.window, dims, batch)

    @functools.cached_property
    def _constants(self) -> scalar.Constants:
        """Constants of the scalar path, built on first use (hashing the config every tick
        would cost more than the lookup saves)."""
        return _scalar_constants(self.config)

    def step(
        self, state: FilterState, inp: ArbitrationInput
    ) -> tuple[FilterState, ArbitrationStep]:
        """One tick: the scalar path for one state, the batched kernel for a batch."""
        states = _single(inp, state)
        if states is not None:
            return _scalar_step(self.mode, self._constants, state, inp, states)
        return self._batched(state, inp, _tick(self.config, inp))

    def _batched(
        self, state: FilterState, inp: ArbitrationInput, t: batched.Tick
    ) -> tuple[FilterState, ArbitrationStep]:
        raise NotImplementedError


@dataclass(frozen=True)
class Manual(_Base):
    """alpha = 0: the robot moves exactly as the hand moves."""

    mode: ClassVar[Mode] = Mode.MANUAL

    def _batched(
        self, state: FilterState, inp: ArbitrationInput, t: batched.Tick
    ) -> tuple[FilterState, ArbitrationStep]:
        return state, _batched_step(t, np.zeros(t.B_raw.shape), t.B_raw, inp.dt)


@dataclass(frozen=True)
class Autonomous(_Base):
    """alpha = 1: the goal-seeking policy alone."""

    mode: ClassVar[Mode] = Mode.AUTONOMOUS

    def _batched(
        self, state: FilterState, inp: ArbitrationInput, t: batched.Tick
    ) -> tuple[FilterState, ArbitrationStep]:
        return state, _batched_step(t, np.ones(t.B_raw.shape), t.B_raw, inp.dt)


@dataclass(frozen=True)
class Standard(_Base):
    """Eq (3): one alpha for all dimensions from the robot's position progress."""

    mode: ClassVar[Mode] = Mode.S

    def _batched(
        self, state: FilterState, inp: ArbitrationInput, t: batched.Tick
    ) -> tuple[FilterState, ArbitrationStep]:
        a = standard_alpha(
            inp.X_goal.position,
            inp.X_current.position,
            inp.X_start.position,
            self.config.eps_trans_m,
        )
        D, N = t.B_raw.shape
        alpha = np.empty((D, N))
        alpha[:] = np.broadcast_to(a, t.batch).reshape(N)
        return state, _batched_step(t, alpha, t.B_raw, inp.dt)


@dataclass(frozen=True)
class DimensionSpecific(_Base):
    """Eq (8) per dimension, with moving windows over B_i and alpha_i."""

    mode: ClassVar[Mode] = Mode.DS

    def _batched(
        self, state: FilterState, inp: ArbitrationInput, t: batched.Tick
    ) -> tuple[FilterState, ArbitrationStep]:
        D = t.B_raw.shape[0]
        shape = (*t.batch, D)
        if state.shape != shape:
            # A filter state with a larger batch than the inputs: broadcast the inputs to it,
            # as numpy broadcasting did; a smaller one cannot hold the tick's values.
            batch = np.broadcast_shapes(state.shape[:-1], t.batch)
            if state.shape != (*batch, D):
                raise ValueError(f"filter state of shape {state.shape} for a tick {shape}")
            t = _tick(self.config, _broadcast_input(inp, batch))
        alpha, B, alpha_rows, B_rows = batched.ds_filter(
            t.P, t.B_raw, state.alpha_rows, state.B_rows, state.count, t.batch
        )
        new = FilterState(alpha_rows, B_rows, state.count + 1)
        return new, _batched_step(t, alpha, B, inp.dt)


def _broadcast_input(inp: ArbitrationInput, batch: tuple[int, ...]) -> ArbitrationInput:
    """The input with every state broadcast to a batch shape."""

    def one(X: HandState) -> HandState:
        return HandState(
            np.broadcast_to(X.position, (*batch, 3)),
            np.broadcast_to(X.rotation, (*batch, 3, 3)),
            np.broadcast_to(X.openness, (*batch, X.n_fingers)),
        )

    return ArbitrationInput(
        X_human=one(inp.X_human),
        X_human_prev=one(inp.X_human_prev),
        X_human_start=one(inp.X_human_start),
        X_current=one(inp.X_current),
        X_prev=one(inp.X_prev),
        X_start=one(inp.X_start),
        X_goal=one(inp.X_goal),
        dt=inp.dt,
        history_term=inp.history_term,
    )


ARBITERS: dict[Mode, type[_Base]] = {
    Mode.DS: DimensionSpecific,
    Mode.S: Standard,
    Mode.MANUAL: Manual,
    Mode.AUTONOMOUS: Autonomous,
}


def make_arbiter(mode: Mode | str, config: ArbitrationConfig | None = None) -> Arbiter:
    """The arbiter of a mode (a Mode or its name: DS, S, manual, autonomous)."""
    m = mode if isinstance(mode, Mode) else Mode.parse(mode)
    arbiter: Arbiter = ARBITERS[m](config or ArbitrationConfig())  # type: ignore[assignment]
    return arbiter
