"""Hypothesis strategies for hand states and arbitration inputs, and helpers that build,
stack and edit inputs (the seven states of an `ArbitrationInput`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from dsteleop.arbitration import ArbitrationInput, HandState, so3_exp

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
coords = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)
angles = st.floats(-4.0, 4.0, allow_nan=False, allow_infinity=False)
unit = st.floats(0.0, 1.0, allow_nan=False, allow_infinity=False)

#: The seven states of an ArbitrationInput, in field order.
STATE_NAMES = (
    "X_human",
    "X_human_prev",
    "X_human_start",
    "X_current",
    "X_prev",
    "X_start",
    "X_goal",
)


def input_from_states(
    states: Sequence[HandState],
    dt: float,
    history_term: NDArray[np.float64] | None = None,
    X_ref: HandState | None = None,
) -> ArbitrationInput:
    """ArbitrationInput from its seven states in field order (X_human, ..., X_goal)."""
    H, Hp, Hs, C, Cp, Cs, G = states
    return ArbitrationInput(
        X_human=H,
        X_human_prev=Hp,
        X_human_start=Hs,
        X_current=C,
        X_prev=Cp,
        X_start=Cs,
        X_goal=G,
        dt=dt,
        history_term=history_term,
        X_ref=X_ref,
    )


def states_of(inp: ArbitrationInput) -> list[HandState]:
    """The seven states of an input in field order."""
    return [getattr(inp, n) for n in STATE_NAMES]


def with_states(inp: ArbitrationInput, **changes: Any) -> ArbitrationInput:
    """The input with some of its fields (states, X_ref, history_term) replaced."""
    return dataclasses.replace(inp, **changes)


def random_state(
    rng: np.random.Generator, batch: tuple[int, ...], n_fingers: int, spread_rad: float = 1.5
) -> HandState:
    """Independent random states: positions in a 1 m cube, random rotations, openness."""
    return HandState(
        rng.uniform(-0.5, 0.5, (*batch, 3)),
        so3_exp(rng.normal(0.0, spread_rad, (*batch, 3))),
        rng.uniform(0.0, 1.0, (*batch, n_fingers)),
    )


def random_input(
    rng: np.random.Generator,
    batch: tuple[int, ...],
    n_fingers: int,
    history: bool = False,
    dt: float = 1.0 / 30.0,
) -> ArbitrationInput:
    """An input of seven independent random states; a (6 + F,) history term if asked."""
    s = [random_state(rng, batch, n_fingers) for _ in STATE_NAMES]
    h = rng.normal(0.0, 0.3, 6 + n_fingers) if history else None
    return input_from_states(s, dt, h)


@st.composite
def hand_states(draw: st.DrawFn, n_fingers: int = 5, big: bool = False) -> HandState:
    c = finite if big else coords
    p = draw(arrays(np.float64, 3, elements=c))
    w = draw(arrays(np.float64, 3, elements=angles))
    g = draw(arrays(np.float64, n_fingers, elements=unit))
    return HandState(p, so3_exp(w), g)


@st.composite
def arbitration_inputs(draw: st.DrawFn, n_fingers: int = 5, big: bool = False) -> ArbitrationInput:
    s = [draw(hand_states(n_fingers, big)) for _ in range(7)]
    dt = draw(st.sampled_from([1 / 30, 1 / 60, 0.01, 0.1]))
    return input_from_states(s, dt)


def stack_states(states: Sequence[HandState], batch: tuple[int, ...] | None = None) -> HandState:
    """Unbatched states stacked on a leading batch axis, reshaped to `batch` if given
    (row-major: state k is at np.unravel_index(k, batch))."""
    shape = (len(states),) if batch is None else batch
    assert math.prod(shape) == len(states)
    F = states[0].openness.shape[-1]
    return HandState(
        np.stack([x.position for x in states]).reshape(*shape, 3),
        np.stack([x.rotation for x in states]).reshape(*shape, 3, 3),
        np.stack([x.openness for x in states]).reshape(*shape, F),
    )


def stack_inputs(
    inputs: Sequence[ArbitrationInput], batch: tuple[int, ...] | None = None
) -> ArbitrationInput:
    """Stack unbatched inputs (same dt, same history term) on a leading batch axis, reshaped
    to `batch` if given; X_ref is stacked when every input has one."""
    states = [stack_states([getattr(i, n) for i in inputs], batch) for n in STATE_NAMES]
    refs = [i.X_ref for i in inputs]
    X_ref = None
    if all(r is not None for r in refs):
        X_ref = stack_states([r for r in refs if r is not None], batch)
    return input_from_states(states, inputs[0].dt, inputs[0].history_term, X_ref)
