"""Task logic without physics: goals, finger schedule, noise, outcomes (robot/task.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.arbitration import ArbitrationInput, HandState, make_arbiter
from dsteleop.arbitration.se3 import so3_exp
from dsteleop.errors import ConfigError
from dsteleop.robot.perception import PerceptionError
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


# --- a robot not told its utensil (goal inference), and its perception error -------------

CANDIDATES = {
    "spoon": (np.array([0.505, 0.3, 0.3]), R_DOWN),
    "spatula": (np.array([0.58, 0.3, 0.3]), R_DOWN),
    "ladle": (np.array([0.655, 0.3, 0.3]), R_DOWN),
}


def _infer(**cfg: Any) -> PickPlaceTask:
    t = PickPlaceTask(
        TaskConfig(**cfg), "spatula", CANDIDATES["spatula"], PLACE, REGIONS, 4, seed=1,
        candidates_true=CANDIDATES, perception=PerceptionError(),
    )  # fmt: skip
    t.start(HandState(np.array([0.58, 0.3, 0.5]), R_DOWN, np.ones(4)), 0.0)
    return t


def _phase(t: PickPlaceTask) -> Phase:
    return t.phase  # a call: mypy keeps no narrowing of the attribute across updates


def _holding(t: float, palm_p: Array, name: str | None) -> TaskObservation:
    return TaskObservation(
        t, HandState(palm_p, R_DOWN, np.ones(4)), np.zeros(3), False, False, holding=name
    )


def test_the_isotropic_error_draws_as_the_told_goal_always_did() -> None:
    """`PerceptionError.isotropic` is the old `_noisy`: position then rotation, per axis."""
    rng, ref = np.random.default_rng(5), np.random.default_rng(5)
    p, R = PerceptionError.isotropic(0.01, 0.05).sample(PICK[0], R_DOWN, rng)
    assert np.array_equal(p, PICK[0] + ref.normal(0.0, 0.01, 3))
    assert np.array_equal(R, so3_exp(ref.normal(0.0, 0.05, 3)) @ R_DOWN)


def test_the_camera_error_is_larger_along_the_view_and_its_sigma_is_its_spread() -> None:
    model = PerceptionError()
    p = CANDIDATES["spatula"][0]
    u = model.ray(p)
    rng = np.random.default_rng(0)
    dp = np.array([model.sample(p, R_DOWN, rng)[0] - p for _ in range(4000)])
    along = dp @ u
    across = dp - along[:, None] * u
    assert np.std(along) == pytest.approx(0.02, rel=0.05)
    assert np.sqrt((across**2).sum(1).mean() / 2) == pytest.approx(0.005, rel=0.05)
    # The belief's per-axis sd is the spread of the draws along each base axis.
    assert np.std(dp, axis=0) == pytest.approx(model.position_sigma(p), rel=0.06)
    sigma = model.sigma(p, 4)
    assert sigma.shape == (10,) and (sigma[3:6] == 0.05).all() and (sigma[6:] == 0).all()
    assert sigma[2] > sigma[0] > sigma[1] > 0.005  # the ray falls steeply, and along +x


def test_a_robot_not_told_chooses_among_the_utensils_then_the_bin() -> None:
    t = _infer(grasp_hold_ticks=3)
    c = t.candidates()
    assert c is not None and c.names == ("spoon", "spatula", "ladle")
    assert c.goals.batch == (3,) and c.sigma.shape == (3, 10)
    assert np.allclose(c.goals.openness, 1.0)
    with pytest.raises(ConfigError, match="not told"):
        _ = t.goal
    # Each candidate closes its own fingers once the palm is near where it is known.
    t.update(_holding(0.1, t.candidates_known["ladle"][0], None))
    c = t.candidates()
    assert c is not None and c.goals.openness[:, 0].tolist() == [1.0, 1.0, 0.0]
    # Whichever utensil the hand holds for the hold ticks is the task's: here not the
    # intended one, and a utensil let go before that restarts the count.
    t.update(_holding(0.2, CANDIDATES["spoon"][0], "spoon"))
    t.update(_holding(0.3, CANDIDATES["spoon"][0], "ladle"))
    t.update(_holding(0.4, CANDIDATES["spoon"][0], "ladle"))
    assert _phase(t) == Phase.PICK
    t.update(_holding(0.5, CANDIDATES["spoon"][0], "ladle"))
    assert _phase(t) == Phase.PLACE and t.utensil == "ladle" and t.intended == "spatula"
    assert [e.detail for e in t.events if e.kind is EventKind.GRASP] == ["ladle"]
    c = t.candidates()
    assert c is not None and c.names == ("bin",) and c.goals.batch == (1,)
    assert np.allclose(c.goals.position[0], t.place_known[0])
    assert np.allclose(t.goal.position, t.place_known[0])


def test_a_robot_not_told_has_no_outcome_before_a_grasp_but_the_timeout() -> None:
    t = _infer(timeout_s=1.0, rest_ticks=2)
    for k in range(5):  # the intended utensil lies on the table: not the task's yet
        t.update(TaskObservation(0.1 * k, HandState(PLACE[0], R_DOWN, np.ones(4)),
                                 np.array([0.9, 0.0, 0.02]), False, False))  # fmt: skip
    assert _outcome(t) is None
    t.update(_holding(1.0, PLACE[0], None))
    out = _outcome(t)
    assert out is not None and out.reason == "timeout" and t.candidates() is None


def test_candidates_are_seeded_and_drawn_from_the_perception_model() -> None:
    a, b = _infer(), _infer()
    for name, (p, _) in CANDIDATES.items():
        assert np.array_equal(a.candidates_known[name][0], b.candidates_known[name][0])
        assert 0 < np.linalg.norm(a.candidates_known[name][0] - p) < 0.1
    quiet = PickPlaceTask(
        TaskConfig(), "spoon", CANDIDATES["spoon"], PLACE, REGIONS, 4, seed=1,
        candidates_true=CANDIDATES, perception=PerceptionError(0.0, 0.0, 0.0),
    )  # fmt: skip
    for name, (p, _) in CANDIDATES.items():
        assert np.array_equal(quiet.candidates_known[name][0], p)
    with pytest.raises(ConfigError, match="isotropic"):
        PerceptionError(0.005, 0.02, 0.05, None)
    with pytest.raises(ConfigError, match="depth_sigma_m"):
        PerceptionError(depth_sigma_m=-1.0)
