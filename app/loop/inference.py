"""The loop's belief over the goal candidates of a robot that is not told its goal.

Input-side, like the tracking's filters (arbitration/ stays pure): the loop keeps one
`GoalInference`, and each tick, while the task offers candidates (`Task.candidates`: the
utensils in the pick phase, the bin in the place phase; docs/METHOD.md §10):

    candidates changed?   other names (a new phase, a reset): a new belief at the prior;
                          the same names with other poses, finger goals or uncertainties
                          (a candidate's fingers closed): the same belief over the new model
    update                with a fresh hand this tick and the one before (X_human and
                          X_human_prev, as eq (6) reads them): Bayes' rule and the floor,
                          `arbitration.belief.GoalBelief.update`, of the hand's step read at
                          the robot's state (x = X_current, x' = `belief.commanded(X_current,
                          X_human, X_human_prev)`: the robot moved by the hand's step, as the
                          study reads it, docs/METHOD.md §10: under assistance the mapped
                          hand drifts from the robot, and its distance to the candidates no
                          longer says where the person wants the robot), over the palm's pose
                          (the 6 pose dimensions, below); otherwise held (a lost, stalled or
                          returning hand is no evidence)
    read                  the MAP candidate's pose is the robot's X_goal; the confidence per
                          dimension (all 6 + F) and joint go to `ArbitrationInput.confidence`
                          and `confidence_joint`

Evidence from the pose alone. Every candidate asks the same of the fingers (open, then closed
at the object: the task's schedule), so the fingers say nothing about which object the person
wants; and a hand that closes is far from every open candidate's finger goal at once, which
adds the same large term under the root of every candidate's cost-to-go (`belief` docstring)
and shrinks the differences between them (read at the hand itself, whose log-odds telescope
to where it is now, a closing hand washed out the evidence of where it went: in the demo's
manual runs the MAP then ended on the grasped utensil in 7 of 18). So the belief is
updated from the pose dimensions of the candidates and of the hand (`GoalBelief` over F = 0
fingers), and the confidence is read over all 6 + F dimensions from the same belief (the
candidates' finger goals included: a candidate whose fingers closed, because the palm came
near it, disagrees in the fingers with the others, so c of each finger is the belief in it).

The belief is a batch of one row (the loop's one robot). Its parameters are
`ArbitrationConfig.belief` (`--param belief.beta=...`), taken at every tick, so a change from
the page or a new configuration applies from the next tick (the belief itself is kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.session.schema import BeliefRecord
from dsteleop.arbitration import HandState
from dsteleop.arbitration.belief import BeliefParams, GoalBelief, commanded
from dsteleop.robot.task import Candidates

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Inferred:
    """What the belief gives the tick.

    Attributes:
        goal: the MAP candidate's pose (the robot's X_goal).
        confidence: (6 + F,) c_i.
        confidence_joint: c_joint.
        record: the belief as the tick records it.
    """

    goal: HandState
    confidence: Array
    confidence_joint: float
    record: BeliefRecord


def _one(X: HandState) -> HandState:
    return HandState(X.position[None], X.rotation[None], X.openness[None])


def _pose(X: HandState) -> HandState:
    """The state without its fingers (F = 0)."""
    return HandState(X.position, X.rotation, np.zeros((*X.batch, 0)))


def _same(a: Candidates, b: Candidates) -> bool:
    return (
        np.array_equal(a.goals.position, b.goals.position)
        and np.array_equal(a.goals.rotation, b.goals.rotation)
        and np.array_equal(a.goals.openness, b.goals.openness)
        and np.array_equal(a.sigma, b.sigma)
    )


class GoalInference:
    """The belief the loop keeps (module docstring)."""

    def __init__(self) -> None:
        self._model: GoalBelief | None = None  # over all 6 + F dimensions: the confidence
        self._pose_model: GoalBelief | None = None  # over the pose: the evidence
        self._candidates: Candidates | None = None
        self._belief: Array | None = None
        self.updates = 0

    def reset(self) -> None:
        """A new trial: the next candidates start at the prior."""
        self._model = self._pose_model = self._candidates = self._belief = None

    def step(
        self,
        candidates: Candidates,
        params: BeliefParams,
        X_robot: HandState,
        X_human: HandState | None,
        X_human_prev: HandState | None,
    ) -> Inferred:
        """One tick (module docstring): `X_robot` the robot's state the tick starts from,
        `X_human` the fresh hand of this tick (None: none), `X_human_prev` the one of the tick
        before (None: none; no evidence this tick)."""
        model, pose_model = self._model, self._pose_model
        if (
            model is None
            or pose_model is None
            or self._candidates is None
            or self._belief is None
            or model.params != params
            or self._candidates.names != candidates.names
            or not _same(self._candidates, candidates)
        ):
            new_names = self._candidates is None or self._candidates.names != candidates.names
            names = candidates.names
            model = GoalBelief(candidates.goals, candidates.sigma, params, names=names)
            pose = _pose(candidates.goals)
            pose_model = GoalBelief(pose, candidates.sigma[:, :6], params, names=names)
            if new_names or self._belief is None:
                self._belief = pose_model.initial(1)
            self._model, self._pose_model, self._candidates = model, pose_model, candidates
        assert self._belief is not None
        if X_human is not None and X_human_prev is not None:
            x = _one(X_robot)
            x_next = commanded(x, _one(X_human), _one(X_human_prev))
            self._belief = pose_model.update(self._belief, _pose(x_next), _pose(x))
            self.updates += 1
        conf = model.confidence(self._belief)
        m = int(conf.map_index[0])
        goal = model.goal_of(conf.map_index)
        per_dim = conf.per_dim[0]
        joint = float(conf.joint[0])
        return Inferred(
            HandState(goal.position[0], goal.rotation[0], goal.openness[0]),
            per_dim,
            joint,
            BeliefRecord(candidates.names, self._belief[0].copy(), m, per_dim, joint),
        )
