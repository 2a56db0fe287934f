"""The operator's previous attempts: the last term of eq (6).

    h_i = (1 / N) * sum_n u(terminal_n, start_n)_i        (0 when N = 0)

Each attempt is one pick or place segment: the hand state where it started and where it
ended. The object is a value (add returns a new history) and serialises to a plain dict; the
app persists it next to the operator's recordings.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.allocation import unit_directions
from dsteleop.arbitration.se3 import HandState, diff
from dsteleop.errors import FormatError

Array = NDArray[np.float64]
SCHEMA = "dsteleop.operator_history/1"


@dataclass(frozen=True)
class Attempt:
    """One finished segment: start and terminal state as (6 + F) [p, rotvec, g] vectors."""

    start: tuple[float, ...]
    terminal: tuple[float, ...]


@dataclass(frozen=True)
class OperatorHistory:
    """Previous attempts of one operator (eq 6, last term)."""

    attempts: tuple[Attempt, ...] = field(default_factory=tuple)

    def __len__(self) -> int:
        return len(self.attempts)

    def add(self, start: HandState, terminal: HandState) -> OperatorHistory:
        """A new history with one more attempt (single, unbatched states)."""
        a = Attempt(_flatten(start), _flatten(terminal))
        return OperatorHistory((*self.attempts, a))

    def term(self, n_fingers: int, threshold: Array) -> Array:
        """Mean unit direction from start to terminal, (6 + F,); zeros with no attempts."""
        dim = 6 + n_fingers
        usable = [a for a in self.attempts if len(a.start) == dim]
        if not usable:
            return np.zeros(dim)
        starts = HandState.from_rotvec(*_split([a.start for a in usable]))
        terms = HandState.from_rotvec(*_split([a.terminal for a in usable]))
        return history_terms(starts, terms, threshold)

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": SCHEMA,
            "attempts": [
                {"start": list(a.start), "terminal": list(a.terminal)} for a in self.attempts
            ],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> OperatorHistory:
        if data.get("schema") != SCHEMA:
            raise FormatError(f"not an operator history (schema {data.get('schema')!r})")
        attempts = []
        for item in data["attempts"]:
            start = tuple(float(v) for v in item["start"])
            terminal = tuple(float(v) for v in item["terminal"])
            if len(start) != len(terminal) or len(start) < 6:
                raise FormatError("operator history attempt has inconsistent lengths")
            if not (np.isfinite(start).all() and np.isfinite(terminal).all()):
                raise FormatError("operator history attempt is not finite")
            attempts.append(Attempt(start, terminal))
        return cls(tuple(attempts))


def _flatten(X: HandState) -> tuple[float, ...]:
    v = np.concatenate([X.position, X.rotvec(), X.openness])
    return tuple(float(x) for x in v)


def _split(rows: list[tuple[float, ...]]) -> tuple[Array, Array, Array]:
    a = np.asarray(rows, dtype=np.float64)
    return a[:, 0:3], a[:, 3:6], a[:, 6:]


def history_terms(starts: HandState, terminals: HandState, threshold: Array) -> Array:
    """The term for a batch of operators at once: their attempts' starts and terminal states,
    batch (..., A) (A attempts each, A >= 1), in; (..., 6 + F) out, the mean over the A
    attempts of the unit directions from start to terminal."""
    d = diff(terminals, starts)  # (..., A, 6 + F)
    # unit_directions is dimension-first: (6 + F, ..., A) in, the mean over the attempts out.
    u = unit_directions(np.moveaxis(d, -1, 0), threshold).mean(-1)
    return np.asarray(np.moveaxis(u, 0, -1))
