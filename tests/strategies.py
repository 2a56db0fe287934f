"""Hypothesis strategies for hand states and arbitration inputs."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from dsteleop.arbitration import ArbitrationInput, HandState, so3_exp

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
coords = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)
angles = st.floats(-4.0, 4.0, allow_nan=False, allow_infinity=False)
unit = st.floats(0.0, 1.0, allow_nan=False, allow_infinity=False)


def input_from_states(
    states: Sequence[HandState], dt: float, history_term: NDArray[np.float64] | None = None
) -> ArbitrationInput:
    """ArbitrationInput from its seven states in field order (X_human, ..., X_goal)."""
    H, Hp, Hs, C, Cp, Cs, G = states
    return ArbitrationInput(H, Hp, Hs, C, Cp, Cs, G, dt=dt, history_term=history_term)


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


def stack_inputs(inputs: list[ArbitrationInput]) -> ArbitrationInput:
    """Stack unbatched inputs (same dt) on a leading batch axis."""
    names = ["X_human", "X_human_prev", "X_human_start", "X_current", "X_prev", "X_start", "X_goal"]
    states = []
    for name in names:
        xs = [getattr(i, name) for i in inputs]
        states.append(
            HandState(
                np.stack([x.position for x in xs]),
                np.stack([x.rotation for x in xs]),
                np.stack([x.openness for x in xs]),
            )
        )
    return input_from_states(states, inputs[0].dt)
