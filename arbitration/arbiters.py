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
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import scalar
from dsteleop.arbitration.allocation import (
    ds_alpha,
    expected_allocation,
    standard_alpha,
    unit_directions,
    willingness,
)
from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.se3 import HandState, integrate, saturate, so3_log

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


@dataclass(frozen=True)
class FilterState:
    """Moving-window buffers of the DS arbiter (batch shape (...), window W, dims D)."""

    alpha_buf: Array  # (..., W, D)
    B_buf: Array  # (..., W, D), starts full of ones
    count: int = 0  # alpha samples seen so far

    @classmethod
    def initial(cls, window: int, dims: int, batch: tuple[int, ...] = ()) -> FilterState:
        return cls(np.zeros((*batch, window, dims)), np.ones((*batch, window, dims)), 0)


@dataclass(frozen=True)
class _Kernel:
    """Mode-independent quantities of one tick."""

    U_human: Array
    U_robot: Array
    P_human: Array
    P_robot: Array
    psi_human: Array
    psi_robot: Array
    B_raw: Array


@functools.lru_cache(maxsize=64)
def _vectors(cfg: ArbitrationConfig, n_fingers: int) -> tuple[Array, Array, Array]:
    """Per-dimension gains, velocity limits and eps (cached: built once per config)."""
    return cfg.gains(n_fingers), cfg.v_max(n_fingers), cfg.eps(n_fingers)


def _stack(arrays: list[Array]) -> Array:
    """Stack on a new first axis, broadcasting batch shapes when they differ."""
    if len({x.shape for x in arrays}) == 1:
        return np.array(arrays)
    return np.array(np.broadcast_arrays(*arrays))


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


def _unbatched(inp: ArbitrationInput) -> bool:
    return all(s.rotation.ndim == 2 and s.position.ndim == 1 for s in _states(inp))


def _kernel(cfg: ArbitrationConfig, inp: ArbitrationInput) -> _Kernel:
    F = inp.X_current.n_fingers
    gains, v_max, eps = _vectors(cfg, F)
    if _unbatched(inp):
        hist = [0.0] * (6 + F) if inp.history_term is None else inp.history_term.tolist()
        return _Kernel(
            *map(
                np.array,
                scalar.kernel(
                    _states(inp),
                    gains.tolist(),
                    v_max.tolist(),
                    eps.tolist(),
                    cfg.kappa,
                    cfg.p,
                    cfg.q,
                    cfg.b,
                    cfg.psi_robot_floor,
                    inp.dt,
                    hist,
                ),
            )
        )
    return _batched_kernel(cfg, inp, gains, v_max, eps)


def _batched_kernel(
    cfg: ArbitrationConfig, inp: ArbitrationInput, gains: Array, v_max: Array, eps: Array
) -> _Kernel:
    H, Hp, Hs = inp.X_human, inp.X_human_prev, inp.X_human_start
    C, Cp, Cs, G = inp.X_current, inp.X_prev, inp.X_start, inp.X_goal

    # The six differences of the tick, stacked on a leading axis, one batched logarithm:
    # 0 goal-cur, 1 hum-hum_prev, 2 goal-hum, 3 hum-hum_start, 4 cur-prev, 5 cur-start.
    left = (G, H, G, H, C, C)
    right = (C, Hp, H, Hs, Cp, Cs)
    R_rel = _stack([s.rotation for s in left]) @ np.swapaxes(
        _stack([s.rotation for s in right]), -1, -2
    )
    rot = so3_log(R_rel)
    pos = _stack([s.position for s in left]) - _stack([s.position for s in right])
    opn = _stack([s.openness for s in left]) - _stack([s.openness for s in right])
    d = np.concatenate([pos, rot, opn], -1)
    # Only the translation and finger entries of goal - start are used (eq 4).
    d_goal_start = np.concatenate([G.position - Cs.position, rot[0], G.openness - Cs.openness], -1)

    # [U_robot, U_human] = sat([K_r * (goal - cur), (hum - hum_prev) / dt])
    scale = np.array([gains, np.full_like(gains, 1.0 / inp.dt)])
    scale = scale.reshape((2,) + (1,) * (d.ndim - 2) + (d.shape[-1],))
    U = saturate(d[:2] * scale, v_max)
    # [P(R), P(H)]: the goal measured from the robot and from the hand.
    P = expected_allocation(d[0:3:2], d_goal_start, eps, cfg.kappa)
    # [psi_robot, psi_human], each agent with its own previous and start states.
    u = unit_directions(d[[4, 1, 5, 3]], eps)
    hist = 0.0 if inp.history_term is None else inp.history_term
    psi = U / v_max - u[:2] - u[2:] + hist
    B_raw = willingness(psi[1], psi[0], cfg.p, cfg.q, cfg.b, cfg.psi_robot_floor)
    return _Kernel(U[1], U[0], P[1], P[0], psi[1], psi[0], B_raw)


def _finish(inp: ArbitrationInput, k: _Kernel, alpha: Array, B: Array) -> ArbitrationStep:
    U_out = k.U_human + alpha * (k.U_robot - k.U_human)  # eq (1)
    X = inp.X_current
    if X.rotation.ndim == 2:
        X_next = scalar.integrate(X, U_out.tolist(), inp.dt)
    else:
        X_next = integrate(X, U_out, inp.dt)  # eq (2)
    return ArbitrationStep(
        alpha=alpha,
        P_human=k.P_human,
        P_robot=k.P_robot,
        B=B,
        psi_human=k.psi_human,
        psi_robot=k.psi_robot,
        U_human=k.U_human,
        U_robot=k.U_robot,
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


@dataclass(frozen=True)
class Manual(_Base):
    """alpha = 0: the robot moves exactly as the hand moves."""

    mode: ClassVar[Mode] = Mode.MANUAL

    def step(
        self, state: FilterState, inp: ArbitrationInput
    ) -> tuple[FilterState, ArbitrationStep]:
        k = _kernel(self.config, inp)
        return state, _finish(inp, k, np.zeros_like(k.U_robot), k.B_raw)


@dataclass(frozen=True)
class Autonomous(_Base):
    """alpha = 1: the goal-seeking policy alone."""

    mode: ClassVar[Mode] = Mode.AUTONOMOUS

    def step(
        self, state: FilterState, inp: ArbitrationInput
    ) -> tuple[FilterState, ArbitrationStep]:
        k = _kernel(self.config, inp)
        return state, _finish(inp, k, np.ones_like(k.U_robot), k.B_raw)


@dataclass(frozen=True)
class Standard(_Base):
    """Eq (3): one alpha for all dimensions from the robot's position progress."""

    mode: ClassVar[Mode] = Mode.S

    def step(
        self, state: FilterState, inp: ArbitrationInput
    ) -> tuple[FilterState, ArbitrationStep]:
        k = _kernel(self.config, inp)
        a = standard_alpha(
            inp.X_goal.position,
            inp.X_current.position,
            inp.X_start.position,
            self.config.eps_trans_m,
        )
        alpha = np.broadcast_to(a[..., None], k.U_robot.shape).copy()
        return state, _finish(inp, k, alpha, k.B_raw)


@dataclass(frozen=True)
class DimensionSpecific(_Base):
    """Eq (8) per dimension, with moving windows over B_i and alpha_i."""

    mode: ClassVar[Mode] = Mode.DS

    def step(
        self, state: FilterState, inp: ArbitrationInput
    ) -> tuple[FilterState, ArbitrationStep]:
        k = _kernel(self.config, inp)
        W = state.B_buf.shape[-2]
        slot = state.count % W
        B_buf = state.B_buf.copy()
        B_buf[..., slot, :] = k.B_raw
        B = B_buf.sum(-2) * (1.0 / W)
        alpha_raw = ds_alpha(k.P_robot, k.P_human, B)
        alpha_buf = state.alpha_buf.copy()
        alpha_buf[..., slot, :] = alpha_raw
        n = min(state.count + 1, W)
        alpha = alpha_buf.sum(-2) / n
        return FilterState(alpha_buf, B_buf, state.count + 1), _finish(inp, k, alpha, B)


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
