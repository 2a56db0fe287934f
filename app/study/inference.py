"""The robot's side of the objects world (app/study/objects.py, docs/operator.md): what it
perceives of the objects in each run, and its belief over them, kept for every row of the
study's batch.

Per run of a person (trajectory n, run a; its own generator seeded by (seed, n, 3, a), drawn
in a fixed order, so a run is the same alone and in any batch, and the same in every mode):

    wanted       the object the person wants, uniform over the K objects
    change       with probability `change_share`, a change of mind at t ~ U(change_at_s) to
                 one of the other objects (uniform); otherwise none (t = inf)
    perceived    each object's x, y, heading as the robot perceives them: the truth plus
                 its perception error (`Objects.perception_error`, through the scene
                 camera) plus the world's goal noise (`Impairments.goal_sigma_m` per position
                 axis, an error the robot does not know about)

`RowBeliefs` keeps the belief of every row of a batch (arbitration/belief.py: one
`GoalBelief` over the rows' own perceived objects, sigma the perception error's sd along each
base axis, the study's `ArbitrationConfig.belief`): each tick it is updated from the hand's
step as the robot receives it (X_human_prev to X_human), read at the robot's state (x =
X_current, x' = `belief.commanded`: under assistance the mapped hand drifts from the robot,
docs/METHOD.md §2 and §10), and gives the robot's goal (the MAP object's
perceived pose) and its confidence per dimension and joint (docs/METHOD.md §10). It records
each row's MAP object per tick, from which `map_stats` gives, over each row's trial, the MAP
at the end, its switches and when it settled on the object the person wanted at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.study.objects import Objects
from dsteleop.arbitration.belief import BeliefParams, Confidence, GoalBelief, commanded
from dsteleop.arbitration.se3 import HandState

Array = NDArray[np.float64]
Index = NDArray[np.intp]


@dataclass(frozen=True)
class ObjectRuns:
    """One run of N people in the objects world (module docstring).

    Attributes:
        true_xy: (K, 2) the objects' true positions [m] (shared).
        normal: the objects' grasp normal [rad] (shared).
        wanted: (N,) the object each person wants at the start.
        final: (N,) the object it wants after its change of mind (= wanted without one).
        change_at_s: (N,) when it changes its mind [s] (inf: it does not).
        perceived: (N, K, 3) each object's x, y [m] and heading [rad] as the robot perceives
            it in this run.
    """

    true_xy: Array
    normal: float
    wanted: Index
    final: Index
    change_at_s: Array
    perceived: Array

    @property
    def changes(self) -> NDArray[np.bool_]:
        """(N,) the people who change their mind (if their run lasts long enough)."""
        return np.asarray(np.isfinite(self.change_at_s))


def draw_runs(
    objects: Objects,
    seed: int,
    indices: NDArray[np.int64],
    attempt: int,
    centre_xy: tuple[float, float],
    normal: float,
    view_axis: tuple[float, float, float],
    goal_sigma_m: float = 0.0,
) -> ObjectRuns:
    """Run `attempt` of the people `indices` (module docstring)."""
    K = objects.count
    N = len(indices)
    wanted = np.zeros(N, dtype=np.intp)
    other = np.zeros(N, dtype=np.intp)
    change_at = np.full(N, np.inf)
    z = np.zeros((N, K, 3))
    noise = np.zeros((N, K, 2))
    lo, hi = objects.change_at_s
    for r, n in enumerate(indices):
        g = np.random.default_rng([seed, int(n), 3, attempt])
        wanted[r] = g.integers(K)
        changes = g.random() < objects.change_share
        t = lo + (hi - lo) * g.random()
        pick = int(g.integers(K - 1)) if K > 1 else 0
        other[r] = pick + (pick >= wanted[r])  # one of the others, uniformly
        if changes and K > 1:
            change_at[r] = t
        z[r] = g.standard_normal((K, 3))
        noise[r] = g.standard_normal((K, 2))
    true_xy = objects.positions(centre_xy)
    error = objects.perception_error(view_axis, z)
    perceived = np.concatenate(
        [true_xy + error[..., :2] + goal_sigma_m * noise, normal + error[..., 2:]], -1
    )
    final = np.where(np.isfinite(change_at), other, wanted)
    return ObjectRuns(true_xy, float(normal), wanted, final, change_at, perceived)


class RowBeliefs:
    """The belief of every row of a batch over its own perceived objects (module docstring).

    Args:
        goals: the objects as the robot perceives them, batch (J, K), one set per row.
        sigma: (J, K, 6 + F) the perception error's sd per dimension (the belief's sigma).
        params: the belief's parameters.
        ticks: the most ticks a trial can have (the MAP record's length).
    """

    def __init__(self, goals: HandState, sigma: Array, params: BeliefParams, ticks: int) -> None:
        self.model = GoalBelief(goals, sigma, params)
        J = goals.batch[0]
        self.belief = self.model.initial(J)
        self.ids = np.arange(J)  # the original row of each current row
        dtype = np.int8 if goals.batch[1] <= 127 else np.int16
        self.map_record = np.zeros((ticks, J), dtype=dtype)  # MAP of each row at each state
        self._now = self.model.confidence(self.belief)
        self.map_record[0] = self._now.map_index

    @property
    def confidence(self) -> Confidence:
        """The current rows' MAP, confidence per dimension and joint."""
        return self._now

    def goal(self) -> HandState:
        """(n,) the current rows' goals: their MAP object's perceived pose."""
        return self.model.goal_of(self._now.map_index)

    def update(
        self, k: int, X_robot: HandState, X_human: HandState, X_human_prev: HandState
    ) -> None:
        """Tick k: Bayes' rule from the hand's step the robot received (state k to k + 1)
        read at the robot's state X_robot (state k), the floor, the new MAP and confidence
        (recorded as state k + 1's MAP)."""
        moved = commanded(X_robot, X_human, X_human_prev)
        self.belief = self.model.update(self.belief, moved, X_robot)
        self._now = self.model.confidence(self.belief)
        self.map_record[k + 1, self.ids] = self._now.map_index

    def keep(self, keep: NDArray[np.bool_]) -> None:
        """Only the current rows `keep` go on."""
        self.model = self.model.take(keep)
        self.belief = self.belief[keep]
        self.ids = self.ids[keep]
        self._now = Confidence(
            self._now.map_index[keep], self._now.per_dim[keep], self._now.joint[keep]
        )


@dataclass(frozen=True)
class MapStats:
    """The MAP object over each row's trial (arrays (J,)).

    Attributes:
        final: the MAP at the trial's last state.
        switches: how often the MAP changed during the trial.
        settled_s: the time from which the MAP stayed on `target` to the end [s] (NaN where
            it did not end there).
    """

    final: Index
    switches: NDArray[np.int64]
    settled_s: Array


def map_stats(
    record: NDArray[np.integer], lengths: NDArray[np.int64], target: Index, dt_s: float
) -> MapStats:
    """`MapStats` of the rows of a `RowBeliefs.map_record` (T, J), each row's trial of
    `lengths` states, against `target` (J,) (the object each row's person wanted at the end)."""
    T = int(lengths.max())
    rec = record[:T]
    J = rec.shape[1]
    cols = np.arange(J)
    last = np.maximum(lengths - 1, 0)
    final = rec[last, cols].astype(np.intp)
    within = np.arange(1, T)[:, None] < lengths[None, :]  # state k (>= 1) is in the trial
    change = (rec[1:] != rec[:-1]) & within
    switches = change.sum(axis=0).astype(np.int64)
    # The last state at which the MAP changed (0: never), then the time from there.
    k_last = np.where(change.any(axis=0), T - 1 - np.argmax(change[::-1], axis=0), 0)
    settled = np.where(final == target, k_last * dt_s, np.nan)
    return MapStats(final, switches, settled)


@dataclass(frozen=True)
class ObjectRows:
    """What the objects world adds to the rows of a batch (arrays (J,)): the object each
    row's person wanted at the end of its run, whether it changed its mind during the run,
    and the MAP object over the run (`MapStats`).

    Attributes:
        true_xy: (K, 2) the objects' true positions [m].
        wanted: the object each row's person wanted at the end of its run.
        changed: the person changed its mind during the run.
        map: the MAP over the run.
    """

    true_xy: Array
    wanted: Index
    changed: NDArray[np.bool_]
    map: MapStats

    def take(self, rows: slice) -> ObjectRows:
        m = self.map
        return ObjectRows(
            self.true_xy,
            self.wanted[rows],
            self.changed[rows],
            MapStats(m.final[rows], m.switches[rows], m.settled_s[rows]),
        )
