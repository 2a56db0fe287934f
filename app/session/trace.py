"""A run as columns: the per-tick arrays that metrics and plots read.

Built from the tick records of a run (recorded, or replayed) by `Trace.of`, the one place
that turns records into arrays. Where the arbitration did not run (stale input) the
per-dimension rows are NaN and `arbitrated` is False.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.session.schema import BeliefRecord, TickRecord
from dsteleop.arbitration import STEP_ARRAYS, ArbitrationStep, HandState, Mode
from dsteleop.robot.task import EventKind, Outcome, Phase

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Trace:
    """Every tick of one run.

    Attributes:
        name: the session (or video) it comes from.
        mode: the arbitration mode of the run.
        dims: dimension names.
        t_s: (T,) tick times from the first tick [s].
        arbitrated: (T,) the arbitration ran.
        step: the arbitration's arrays stacked over time, each (T, D) (NaN where it did not
            run); `step.X_next` holds the commanded states (T, ...).
        p_human: (T, 3) the mapped hand position [m], NaN where there was none.
        p_robot: (T, 3) the robot's achieved palm position [m].
        p_goal: (T, 3) the goal the robot knew [m], NaN once the task was done.
        phases: (T,) the task phase after each tick.
        outcome: how the run ended, or None.
        time_s: the time from the first tick to the outcome, or the run's length [s].
        v_max: (D,) velocity limits of the run's arbitration.
        beliefs: (T,) the belief over the goal candidates after each tick (None: told).
        grasped: the utensil of the run's first grasp event, or None.
    """

    name: str
    mode: Mode
    dims: tuple[str, ...]
    t_s: Array
    arbitrated: NDArray[np.bool_]
    step: ArbitrationStep
    p_human: Array
    p_robot: Array
    p_goal: Array
    phases: tuple[Phase, ...]
    outcome: Outcome | None
    time_s: float
    v_max: Array
    beliefs: tuple[BeliefRecord | None, ...] = ()
    grasped: str | None = None

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @classmethod
    def of(cls, name: str, mode: Mode, records: Sequence[TickRecord], v_max: Array) -> Trace:
        T = len(records)
        dims = records[0].dims if records else ()
        D = len(dims)
        arrays = {k: np.full((T, D), np.nan) for k in STEP_ARRAYS}
        arbitrated = np.zeros(T, dtype=bool)
        nan3 = np.full(3, np.nan)
        p_h, p_r, p_g = np.full((T, 3), np.nan), np.full((T, 3), np.nan), np.full((T, 3), np.nan)
        nxt_p, nxt_R, nxt_g = np.zeros((T, 3)), np.zeros((T, 3, 3)), np.zeros((T, max(D - 6, 0)))
        for k, r in enumerate(records):
            if r.step is not None:
                arbitrated[k] = True
                for a in STEP_ARRAYS:
                    arrays[a][k] = getattr(r.step, a)
            X = r.hand.X_human if r.hand is not None else None
            p_h[k] = nan3 if X is None else X.position
            p_r[k] = r.X_current.position
            p_g[k] = nan3 if r.X_goal is None else r.X_goal.position
            nxt_p[k], nxt_R[k], nxt_g[k] = r.X_next.position, r.X_next.rotation, r.X_next.openness
        t = np.array([r.t_s for r in records], dtype=np.float64)
        t0 = float(t[0]) if T else 0.0
        outcome = next((r.outcome for r in records if r.outcome is not None), None)
        end = next((r.t_s for r in records if r.outcome is not None), None)
        duration = float(t[-1] - t0) if T > 1 else 0.0
        return cls(
            name=name,
            mode=mode,
            dims=dims,
            t_s=t - t0,
            arbitrated=arbitrated,
            step=ArbitrationStep(**arrays, X_next=HandState(nxt_p, nxt_R, nxt_g)),
            p_human=p_h,
            p_robot=p_r,
            p_goal=p_g,
            phases=tuple(r.phase for r in records),
            outcome=outcome,
            time_s=(end - t0) if end is not None else duration,
            v_max=np.asarray(v_max, dtype=np.float64),
            beliefs=tuple(r.belief for r in records),
            grasped=next(
                (
                    e.detail or None
                    for r in records
                    for e in r.plant.events
                    if e.kind is EventKind.GRASP
                ),
                None,
            ),
        )

    @property
    def success(self) -> bool:
        return self.outcome is not None and self.outcome.success

    @property
    def outcome_name(self) -> str:
        """ "success", "failure" or "none"."""
        if self.outcome is None:
            return "none"
        return "success" if self.outcome.success else "failure"

    @property
    def recorded_s(self) -> float:
        return float(self.t_s[-1]) if len(self) else 0.0

    def finite_time(self) -> float | None:
        return self.time_s if math.isfinite(self.time_s) and self.time_s > 0 else None
