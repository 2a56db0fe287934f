"""The closed-loop operator (docs/operator.md): one test per mechanism, against simple robots.

The robots here are plain functions of the hand (no arbitration, no physics): a robot that
follows the hand exactly (manual), one offset from it (its goal is wrong), one that does not
move at all. The operator steers the *robot*, so each test checks what it does to the robot.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.operator.closed_loop import ClosedLoopOperator
from dsteleop.app.operator.person import Intention, OperatorProfile
from dsteleop.app.operator.world import CommandDelay, Impairments
from dsteleop.arbitration import HandState, so3_exp
from dsteleop.arbitration.se3 import stack

DT = 1.0 / 30.0
Robot = Callable[[HandState, HandState], HandState]  # (hand now, robot before) -> robot now


def planar(x: float, y: float, heading: float) -> HandState:
    return HandState(np.array([x, y, 0.0]), so3_exp(np.array([0.0, 0.0, heading])), np.zeros(0))


def one_stage(
    target: HandState, n: int, tol: tuple[float, float] = (0.01, 0.05), turn_within_m: float = 1.0
) -> Intention:
    """n operators who want the robot at `target` (one stage), within `tol`."""
    t = stack([stack([target])] * n)
    return Intention(
        t,
        np.tile([tol[0], tol[1], 1.0], (n, 1, 1)),
        np.tile([1.0, 1.0, 0.0, 0.0, 0.0, 1.0], (n, 1, 1)),  # x, y and the heading
        np.ones(n, dtype=np.int64),
        np.full(n, turn_within_m),
    )


#: The mechanisms of the person alone: no link delay, the robot seen as well along the view as
#: across it (the world's impairments have their own tests below).
CLEAR = Impairments.unimpaired()


def operators(
    n: int,
    seed: int = 0,
    target: HandState | None = None,
    world: Impairments = CLEAR,
    intention: Intention | None = None,
    **profile: object,
) -> ClosedLoopOperator:
    start = stack([planar(0.0, 0.0, 0.0)] * n)
    rngs = [np.random.default_rng([seed, i]) for i in range(n)]
    target = target or planar(0.3, 0.4, 0.5)
    plan = intention or one_stage(target, n)
    return ClosedLoopOperator(plan, start, OperatorProfile(**profile), rngs, world=world)  # type: ignore[arg-type]


def run(
    op: ClosedLoopOperator, robot: Robot, seconds: float
) -> tuple[list[HandState], list[HandState]]:
    """Tick the operator against `robot`; the hands and robots of every tick."""
    X = op.start
    hands, robots = [op.start], [X]
    op.observe(0.0, X)
    for k in range(1, round(seconds / DT) + 1):
        t = k * DT
        H = op.hand(t)
        X = robot(H, X)
        op.observe(t, X)
        hands.append(H)
        robots.append(X)
        if op.done.all():
            break
    return hands, robots


def follows(H: HandState, X: HandState) -> HandState:
    return H


def error_m(X: HandState, target: HandState) -> NDArray[np.float64]:
    return np.asarray(np.linalg.norm(X.position - target.position, axis=-1))


def test_same_seed_same_hands_and_rows_do_not_depend_on_the_batch() -> None:
    a_h, _ = run(operators(3, seed=4), follows, 6.0)
    b_h, _ = run(operators(3, seed=4), follows, 6.0)
    for a, b in zip(a_h, b_h, strict=True):
        assert np.array_equal(a.position, b.position) and np.array_equal(a.rotation, b.rotation)
    # Row 1 alone is row 1 of the batch (each row draws from its own generator).
    alone = ClosedLoopOperator(
        one_stage(planar(0.3, 0.4, 0.5), 1),
        stack([planar(0.0, 0.0, 0.0)]),
        OperatorProfile(),
        [np.random.default_rng([4, 1])],
        world=CLEAR,
    )
    c_h, _ = run(alone, follows, 6.0)
    n = min(len(c_h), len(a_h))
    for k in range(n):
        np.testing.assert_allclose(c_h[k].position[0], a_h[k].position[1], atol=1e-12)
    c, _ = run(operators(3, seed=5), follows, 6.0)
    assert not np.array_equal(c[-1].position, a_h[-1].position)


def test_reaction_time_before_the_first_submovement() -> None:
    """Nothing moves before the perception delay plus a decision time (0.25-0.55 s)."""
    op = operators(20, seed=1)
    hands, _ = run(op, follows, 1.0)
    moved_at = []
    for row in range(20):
        k = next(k for k, H in enumerate(hands) if np.any(H.position[row] != 0.0))
        moved_at.append(k * DT)
    lo = OperatorProfile().delay_s[0] + OperatorProfile().decision_s[0]
    hi = OperatorProfile().delay_s[1] + OperatorProfile().decision_s[1]
    assert min(moved_at) >= lo - DT and max(moved_at) <= hi + 2 * DT
    assert np.ptp(moved_at) > 0.05  # each person its own delay


def test_submovements_are_minimum_jerk_and_intermittent() -> None:
    """The first submovement starts and ends at rest with a single speed peak in the middle,
    then the hand dwells (holds still) before the next one."""
    op = operators(1, seed=2)
    hands, _ = run(op, follows, 10.0)
    p = np.array([H.position[0, :2] for H in hands])
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / DT
    moving = speed > 1e-6
    start = int(np.argmax(moving))
    end = start + int(np.argmax(~moving[start:]))  # the first rest after it
    seg = speed[start:end]
    assert len(seg) >= 8
    peak = int(np.argmax(seg))
    assert 0.3 * len(seg) <= peak <= 0.7 * len(seg)  # bell-shaped: the peak near the middle
    assert seg[0] < 0.25 * seg[peak] and seg[-1] < 0.25 * seg[peak]
    dwell = int(np.argmax(moving[end:]))
    assert dwell * DT >= OperatorProfile().delay_s[0] + OperatorProfile().decision_s[0] - 2 * DT
    assert np.all(speed <= OperatorProfile().v_cap_mps + 1e-9)


def test_satisfied_within_its_tolerance_then_done() -> None:
    """A robot that follows the hand: the operator brings it within its tolerance (as it
    sees it: each person misjudges the robot's position by a few mm), holds, and commits
    (not given up), well before its patience."""
    op = operators(30, seed=3)
    target = planar(0.3, 0.4, 0.5)
    _, robots = run(op, follows, 30.0)
    assert op.done.all() and not op.gave_up.any() and op.committed.all()
    err = error_m(robots[-1], target)
    assert np.all(err <= 0.01 + 0.012) and np.median(err) <= 0.01
    assert np.all(op.t_done > 1.0) and np.all(op.t_done < 20.0)
    assert np.median(op.t_done) < 9.0


def test_it_steers_the_robot_not_its_hand() -> None:
    """The robot sits 3 cm off the hand (a goal error): the operator corrects the ROBOT to
    its target; its hand ends 3 cm off the target."""
    offset = np.array([0.03, -0.03, 0.0]) / math.sqrt(2)

    def shifted(H: HandState, X: HandState) -> HandState:
        return HandState(H.position + offset, H.rotation, H.openness)

    op = operators(10, seed=6)
    target = planar(0.3, 0.4, 0.5)
    hands, robots = run(op, shifted, 30.0)
    assert op.done.all() and not op.gave_up.any()
    err = error_m(robots[-1], target)
    assert np.all(err <= 0.01 + 0.012) and np.median(err) <= 0.01
    hand_err = error_m(hands[-1], target)
    assert np.median(np.abs(hand_err - 0.03)) < 0.012


def test_pushes_harder_when_resisted_then_pauses_and_gives_up() -> None:
    """A robot that does not move: each resisted submovement is larger (the gain grows by
    push_gain_step up to push_gain_max), after a few it pauses, and after its patience it
    gives up, holding still."""
    patience = 8.0
    op = operators(4, seed=7, target=planar(0.06, 0.08, 0.0), patience_s=patience)
    stuck = planar(0.0, 0.0, 0.0)

    def still(H: HandState, X: HandState) -> HandState:
        return stack([stuck] * 4)

    hands, _ = run(op, still, 20.0)
    assert op.done.all() and op.gave_up.all()
    np.testing.assert_allclose(op.t_done, patience, atol=DT)
    # Submovement amplitudes of row 0: growing while resisted, bounded by push_gain_max.
    p = np.array([H.position[0, :2] for H in hands])
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    moving = step > 1e-9
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    starts, ends = edges[::2] + 1, edges[1::2] + 1
    amps = [np.linalg.norm(p[e] - p[s]) for s, e in zip(starts, ends, strict=False)]
    # The target is 0.1 m away and the robot never moves: the first submovement asks for the
    # whole error, the next ones for 1.5x, 2.25x, ... up to 3x.
    assert amps[1] > 1.2 * amps[0] and amps[2] > 1.2 * amps[1]
    assert max(amps) <= OperatorProfile().push_gain_max * 0.1 * 1.25
    # A pause after `resisted_before_pause` resisted submovements: the longest rest between
    # two submovements is at least the shortest pause.
    rests = (starts[1:] - ends[: len(starts) - 1]) * DT
    assert rests.max() >= OperatorProfile().pause_s[0]
    # Given up: the hand holds still afterwards.
    after = [op.hand(float(op.t_done.max()) + k * DT).position.copy() for k in range(1, 4)]
    np.testing.assert_array_equal(after[0], after[-1])


def test_validation() -> None:
    with pytest.raises(ValueError, match="delay_s"):
        OperatorProfile(delay_s=(0.3, 0.1))
    with pytest.raises(ValueError, match="patience_s"):
        OperatorProfile(patience_s=0.0)
    with pytest.raises(ValueError, match="share"):
        OperatorProfile().for_robot(0.25, 1.0, 4.0, share=1.5)


# --- the world's impairments (docs/operator.md), one mechanism each ---------------------------


def test_one_camera_view_misjudges_depth_more_than_lateral_position() -> None:
    """Through one camera looking along x, the robot's position is misjudged along x (depth)
    several times more than across it: over 300 people steering a robot that follows the
    hand, the robots' final errors along x spread ~5x wider than along y."""
    world = Impairments(depth_sigma_m=0.015, lateral_sigma_m=0.003, delay_s=0.0)
    n = 300
    op = operators(n, seed=11, world=world, target=planar(0.3, 0.4, 0.0))
    _, robots = run(op, follows, 30.0)
    assert op.committed.mean() >= 0.95
    err = robots[-1].position[op.committed, :2] - np.array([0.3, 0.4])
    sd_x, sd_y = err.std(axis=0)
    assert 0.010 < sd_x < 0.020 and sd_y < 0.006 and sd_x > 3 * sd_y
    # The misjudgement itself: sd depth_sigma along the view, lateral_sigma across.
    m = op.misjudged
    assert m[:, 0].std() == pytest.approx(0.015, rel=0.15)
    assert m[:, 1].std() == pytest.approx(0.003, rel=0.15)
    # Turned to look along y, the same people misjudge y instead.
    turned = operators(n, seed=11, world=world.replace(view_axis=(0.0, 1.0, 0.0)))
    assert turned.misjudged[:, 1].std() > 3 * turned.misjudged[:, 0].std()


def test_the_link_delays_what_the_operator_sees() -> None:
    """The image path: the person sees the robot `delay_s` later, so the same people (same
    seeds) make their first move `delay_s` later, and dwell 2 delay_s longer between
    submovements (they wait the round trip for each movement's effect)."""
    n, delay = 20, 0.4

    def first_moves(world: Impairments) -> NDArray[np.float64]:
        hands, _ = run(operators(n, seed=1, world=world), follows, 2.0)
        return np.array(
            [next(k for k, H in enumerate(hands) if np.any(H.position[r] != 0.0)) for r in range(n)]
        )

    shift = (first_moves(CLEAR.replace(delay_s=delay)) - first_moves(CLEAR)) * DT
    np.testing.assert_allclose(shift, delay, atol=1.01 * DT)


def test_the_command_delay_line() -> None:
    """The command path: the robot receives the hand `ticks` ticks late (the start before)."""
    start = stack([planar(0.0, 0.0, 0.0)] * 2)
    line = CommandDelay(start, 3)
    got = [line.push(stack([planar(0.01 * k, 0.0, 0.0)] * 2)).position[0, 0] for k in range(1, 7)]
    np.testing.assert_allclose(got, [0.0, 0.0, 0.0, 0.01, 0.02, 0.03])
    line.select(np.array([False, True]))
    assert line.push(stack([planar(1.0, 0.0, 0.0)])).position.shape == (1, 3)
    assert CommandDelay(start, 0).push(start) is start


def test_a_resisted_preference_settles_for_the_task() -> None:
    """A robot that follows the hand's position but never turns: people who want a heading
    0.5 rad off give up when they never settle; with the task's goal and tolerance to settle
    for (heading 0 within 0.35 rad), they settle after the resistance and commit."""
    n = 20
    target = planar(0.3, 0.4, 0.5)

    def no_turn(H: HandState, X: HandState) -> HandState:
        return HandState(H.position, X.rotation, H.openness)

    plain = operators(n, seed=8, target=target, patience_s=20.0)
    run(plain, no_turn, 25.0)
    assert plain.gave_up.all() and not plain.settled.any()
    it = one_stage(target, n)
    settle = Intention(
        it.targets, it.tolerance, it.mask, it.n_stages, it.turn_within_m,
        one_stage(planar(0.3, 0.4, 0.0), n).targets, np.tile([0.03, 0.35, 1.0], (n, 1, 1)),
    )  # fmt: skip
    settling = operators(n, seed=8, intention=settle, patience_s=20.0)
    _, robots = run(settling, no_turn, 25.0)
    assert settling.settled.all() and settling.committed.mean() >= 0.95
    err = error_m(robots[-1], target)[settling.committed]  # as seen: within 3 cm
    assert np.all(err <= 0.03 + 0.012) and np.median(err) <= 0.02
