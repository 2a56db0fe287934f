"""Task logic without physics: goals, finger schedule, noise, outcomes (robot/task.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.arbitration import ArbitrationInput, HandState, make_arbiter
from dsteleop.arbitration.se3 import so3_exp
from dsteleop.robot.scripted import goal_seeking_step
from dsteleop.robot.task import (
    EventKind,
    Outcome,
    Phase,
    PickPlaceTask,
    Region,
    SceneRegions,
    TaskConfig,
    TaskObservation,
)

Array = NDArray[np.float64]
R_DOWN = np.diag([-1.0, 1.0, -1.0])
PICK = (np.array([0.5, 0.3, 0.3]), R_DOWN)
PLACE = (np.array([0.58, -0.26, 0.45]), R_DOWN)
REGIONS = SceneRegions(
    bin_inner=Region((0.4, -0.44, 0.0), (0.76, -0.08, 0.4)),
    holder=Region((0.46, 0.19, 0.0), (0.70, 0.33, 0.4)),
    floor_below_z_m=-0.1,
)


def _task(**cfg: Any) -> PickPlaceTask:
    t = PickPlaceTask(TaskConfig(**cfg), "spoon", PICK, PLACE, REGIONS, 4, seed=1)
    t.start(HandState(np.array([0.58, 0.3, 0.5]), R_DOWN, np.ones(4)), 0.0)
    return t


def _obs(
    t: float, palm_p: Array, utensil_p: Array, held: bool = False, touching: bool = False
) -> TaskObservation:
    return TaskObservation(
        t,
        HandState(palm_p, R_DOWN, np.ones(4)),
        utensil_p,
        held,
        touching,
    )


def _outcome(t: PickPlaceTask) -> Outcome | None:
    return t.outcome  # a call: mypy keeps no narrowing of the attribute across updates


def test_noise_is_seeded_and_configurable() -> None:
    a = _task()
    b = _task()
    assert np.array_equal(a.pick_known[0], b.pick_known[0])
    assert not np.allclose(a.pick_known[0], PICK[0])
    c = _task(goal_noise_pos_m=0.0, goal_noise_rot_rad=0.0)
    assert np.array_equal(c.pick_known[0], PICK[0]) and np.array_equal(c.pick_known[1], R_DOWN)


def test_fingers_close_near_the_pick_goal_and_place_activates_on_grasp() -> None:
    t = _task(goal_noise_pos_m=0.0, goal_noise_rot_rad=0.0, grasp_hold_ticks=3)
    in_holder = np.array([0.5, 0.28, 0.14])
    t.update(_obs(0.1, np.array([0.5, 0.3, 0.4]), in_holder))
    assert t.goal.openness == pytest.approx(np.ones(4))  # far: approach open
    t.update(_obs(0.2, PICK[0] + 0.002, in_holder))
    assert t.goal.openness == pytest.approx(np.zeros(4))  # near: close (latched)
    t.update(_obs(0.3, np.array([0.5, 0.3, 0.4]), in_holder))
    assert t.goal.openness == pytest.approx(np.zeros(4))
    for k in range(3):
        t.update(_obs(0.4 + 0.1 * k, PICK[0], in_holder, held=True, touching=True))
    assert t.phase == Phase.PLACE
    assert t.X_start is not None and np.allclose(t.X_start.position, PICK[0])
    assert [e.kind for e in t.events] == [EventKind.GOAL, EventKind.GRASP, EventKind.GOAL]
    assert np.allclose(t.goal.position, PLACE[0])


@pytest.mark.parametrize(
    ("p", "success", "reason"),
    [
        ((0.58, -0.26, 0.05), True, "in_bin"),
        ((0.40, 0.00, 0.01), False, "on_table"),
        ((0.40, 0.00, -0.70), False, "on_floor"),
    ],
)
def test_outcome_needs_the_utensil_at_rest_and_untouched(
    p: tuple[float, ...], success: bool, reason: str
) -> None:
    t = _task(rest_ticks=5)
    palm = np.array([0.58, 0.3, 0.5])
    u = np.array(p)
    for k in range(10):  # touched: no outcome however long it rests
        t.update(_obs(0.1 * k, palm, u, touching=True))
    assert _outcome(t) is None
    for k in range(3):  # moving: no outcome
        t.update(_obs(1.0 + 0.1 * k, palm, u + np.array([0.0, 0.0, 0.01 * k])))
    assert _outcome(t) is None
    for k in range(6):
        t.update(_obs(2.0 + 0.1 * k, palm, u))
    out = _outcome(t)
    assert out is not None
    assert (out.success, out.reason) == (success, reason)
    assert t.phase == Phase.DONE
    assert t.events[-1].kind == (EventKind.SUCCESS if success else EventKind.FAILURE)


def test_resting_in_the_holder_is_no_outcome_until_the_timeout() -> None:
    t = _task(rest_ticks=3, timeout_s=2.0)
    for k in range(90):
        t.update(_obs(k / 30.0, np.array([0.58, 0.3, 0.5]), np.array([0.5, 0.28, 0.14])))
        if k == 30:
            assert _outcome(t) is None  # at rest in the holder for a second: nothing yet
    out = _outcome(t)
    assert out is not None and out.reason == "timeout"
    assert out.time_s == pytest.approx(2.0, abs=1 / 30)


def test_scripted_policy_is_the_autonomous_arbiter() -> None:
    X = HandState(np.array([0.5, 0.1, 0.4]), so3_exp(np.array([3.0, 0.1, 0.0])), np.ones(4))
    G = HandState(np.array([0.6, 0.3, 0.3]), so3_exp(np.array([2.9, 0.0, 0.3])), np.zeros(4))
    arbiter = make_arbiter("autonomous")
    _, out = arbiter.step(
        arbiter.initial_state(10),
        ArbitrationInput(
            X_human=X,
            X_human_prev=X,
            X_human_start=X,
            X_current=X,
            X_prev=X,
            X_start=X,
            X_goal=G,
            dt=1 / 30,
        ),
    )
    Y = goal_seeking_step(X, G, 1 / 30)
    assert np.allclose(out.X_next.position, Y.position)
    assert np.allclose(out.X_next.rotation, Y.rotation)
    assert np.allclose(out.X_next.openness, Y.openness)
