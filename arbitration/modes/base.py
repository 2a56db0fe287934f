"""What a mode plug-in is: the quantities its alpha rule reads, and its registry entry.

One tick (`arbiters.py`) computes everything but alpha once for every row of a batch (the
shared part: U_robot, U_human, P(H), P(R), psi, B and eq (3)'s distances), then runs each
mode's alpha rule on that mode's rows, then eq (1)-(2) for every row. A mode is therefore:

    name          how it is written (command line, sessions, reports): "DS", "scalar"
    attribute     its name on `Mode` (`Mode.DS`, `Mode.SCALAR`)
    alpha         its rule, `alpha(params, q, rows, state) -> state`: writes q.alpha[rows]
                  (rows (R,) indices into the batch) and may overwrite q.B[rows] with the B it
                  used (DS reports its filtered B); returns its new own state
    params        its own hyper-parameters: a frozen dataclass validated at construction (a
                  ConfigError naming the field as `<name>.<field>`), or None
    space         its default search space for `dsteleop tune --mode NAME` (NAME=SPEC items of
                  app/tune/space.py; its own parameters are `<name>.<field>`)
    initial_state its own filter state for a batch of M rows (None: it has none); a state has
                  `select(keep)`, the state of the rows `keep`
    reads_allocation  whether its rule reads P(H), P(R), psi or B (eq 4-7; True unless it
                  says otherwise): a caller that needs only the actions (the study,
                  `Arbiter.step(..., every_quantity=False)`) skips them for the other rows
    shorthands    names that set several of its parameters at once (`DS.cap` sets DS's three
                  caps); written configurations hold only the parameters themselves, and a
                  parameter given by its own name wins over a shorthand that sets it
    reads_confidence  whether its rule reads the robot's confidence in its goal (False unless
                  it says otherwise): the study's default modes leave such a mode out, since
                  its worlds tell the robot its goal (confidence 1)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, NamedTuple, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import ConfigError

if TYPE_CHECKING:
    from dsteleop.arbitration.config import ArbitrationConfig

Array = NDArray[np.float64]
Rows = NDArray[np.intp]


class Quantities(NamedTuple):
    """The shared quantities of one tick, for the M rows of its batch (flattened); a named
    tuple (made every tick: cheaper than a dataclass).

    Attributes:
        alpha: (M, 6 + F) the output the alpha rules write, each into its own rows.
        P_human, P_robot: (M, 6 + F) eq (4)/(5).
        B: (M, 6 + F) eq (7), raw (a rule may overwrite its rows with the B it used).
        psi_human, psi_robot: (M, 6 + F) eq (6).
        U_human, U_robot: (M, 6 + F) the two actions (m/s, rad/s, 1/s).
        l1_goal_current_m: (M,) |p_goal - p_current|_1, the robot's position [m].
        l1_goal_start_m: (M,) max(|p_goal - p_start|_1, alloc_floor_m), eq (3)'s
            denominator [m].
        confidence: (M, 6 + F) the robot's confidence c_i in each dimension of its goal, in
            [0, 1] (`ArbitrationInput.confidence`; ones for a goal it is told), read-only.
        confidence_joint: (M,) its confidence in the whole goal at once, in [0, 1], read-only.
    """

    alpha: Array
    P_human: Array
    P_robot: Array
    B: Array
    psi_human: Array
    psi_robot: Array
    U_human: Array
    U_robot: Array
    l1_goal_current_m: Array
    l1_goal_start_m: Array
    confidence: Array
    confidence_joint: Array


class ModeState(Protocol):
    """A mode's own filter state for the rows of a batch."""

    def select(self, keep: NDArray[np.bool_]) -> ModeState: ...


#: A mode's own parameters (a frozen dataclass, or None when it has none).
P = TypeVar("P")
#: A mode's own filter state (None when it has none).
S = TypeVar("S", bound="ModeState | None")

#: An alpha rule over parameters P and state S: `alpha(params, q, rows, state) -> state`.
AlphaRule = Callable[[P, Quantities, Rows, S], S]


@dataclass(frozen=True)
class ModeSpec(Generic[P, S]):
    """One mode plug-in (module docstring), generic over its parameters P and its state S,
    so that a plug-in's rule, parameter class and initial state are checked against each
    other (a registry of several modes holds `ModeSpec[Any, Any]`).

    Attributes:
        name: its written name.
        attribute: its name on `Mode` (upper case).
        alpha: its alpha rule.
        summary: what it is, in one line.
        params: the class of its own parameters (a frozen dataclass), or None.
        space: its default `dsteleop tune` search space.
        initial_state: (config, dims, M) -> its own filter state, or None.
        reads_allocation: its rule reads P_human, P_robot, psi_human, psi_robot or B of
            `Quantities` (False: only the actions, alpha and eq (3)'s distances).
        shorthands: (shorthand, the parameters it sets) pairs.
        reads_confidence: its rule reads the robot's confidence in its goal (`Quantities.
            confidence`); the study's worlds tell the robot its goal (confidence 1, where such
            a mode is the one it tempers, exactly), so the study runs it only when asked
            (`--modes`), not by default.
    """

    name: str
    attribute: str
    alpha: AlphaRule[P, S]
    summary: str
    params: type[P] | None = None
    space: tuple[str, ...] = ()
    initial_state: Callable[[ArbitrationConfig, int, int], S] | None = None
    reads_allocation: bool = True
    reads_confidence: bool = False
    shorthands: tuple[tuple[str, tuple[str, ...]], ...] = ()


def check_range(
    mode: str, name: str, value: Any, low: float, high: float, low_open: bool = True
) -> None:
    """A mode parameter must be a finite number in (low, high] (or [low, high]); else a
    ConfigError naming it as `<mode>.<name>`."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{mode}.{name} must be a number, got {value!r}")
    below = value <= low if low_open else value < low
    if not math.isfinite(value) or below or value > high:
        bracket = "(" if low_open else "["
        raise ConfigError(f"{mode}.{name} must be in {bracket}{low:g}, {high:g}], got {value!r}")
