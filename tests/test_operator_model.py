"""The synthetic operator: seeded reproducibility, goal reaching, strategies, speed caps."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dsteleop.app.operator.open_loop import (
    OperatorStrategy,
    min_jerk,
    sample_trajectory,
    stack,
)
from dsteleop.arbitration import HandState, so3_log

DT = 1.0 / 30.0
PLANAR = OperatorStrategy(noise_dims=(True, True, False, False, False, True))


def start_6d() -> HandState:
    return HandState.from_rotvec([0.3, 0.0, 0.2], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0])


def goal_6d() -> HandState:
    return HandState.from_rotvec([0.5, 0.25, 0.05], [0.3, -0.2, 0.9], [0.1, 0.2, 0.2, 0.3])


def test_same_seed_same_trajectory_bit_for_bit() -> None:
    a = sample_trajectory(start_6d(), goal_6d(), DT, 7)
    b = sample_trajectory(start_6d(), goal_6d(), DT, np.random.default_rng(7))
    assert np.array_equal(a.t_s, b.t_s)
    assert np.array_equal(a.states.position, b.states.position)
    assert np.array_equal(a.states.rotation, b.states.rotation)
    assert np.array_equal(a.states.openness, b.states.openness)
    c = sample_trajectory(start_6d(), goal_6d(), DT, 8)
    assert len(a) != len(c) or not np.array_equal(a.states.position, c.states.position)


@pytest.mark.parametrize("seed", range(20))
def test_trajectory_starts_at_start_and_ends_near_goal(seed: int) -> None:
    st = OperatorStrategy()
    tr = sample_trajectory(start_6d(), goal_6d(), DT, seed, st)
    X = tr.states
    assert X.position.shape == (len(tr), 3) and X.rotation.shape == (len(tr), 3, 3)
    assert X.openness.shape == (len(tr), 4)
    np.testing.assert_allclose(X.position[0], start_6d().position, atol=1e-12)
    np.testing.assert_allclose(X.rotation[0], start_6d().rotation, atol=1e-12)
    # Ends at the drawn target, within a few endpoint standard deviations of the goal.
    np.testing.assert_allclose(X.position[-1], tr.sample.target.position, atol=1e-9)
    assert np.linalg.norm(X.position[-1] - goal_6d().position) < 5 * st.endpoint_sd_m * np.sqrt(3)
    err = so3_log(X.rotation[-1] @ goal_6d().rotation.T)
    assert np.linalg.norm(err) < 5 * st.endpoint_sd_rad * np.sqrt(3)
    np.testing.assert_allclose(X.openness[-1], goal_6d().openness, atol=1e-9)
    # Rotations stay rotations; openness stays in [0, 1].
    RtR = np.einsum("tji,tjk->tik", X.rotation, X.rotation)
    np.testing.assert_allclose(RtR, np.broadcast_to(np.eye(3), RtR.shape), atol=1e-9)
    assert (X.openness >= 0).all() and (X.openness <= 1).all()
    # The hand holds still at the end (the hold time).
    hold = int(tr.sample.hold_s / DT) - 1
    assert np.ptp(X.position[-hold:], axis=0).max() < 1e-9


@pytest.mark.parametrize("seed", range(10))
def test_speed_stays_under_the_caps(seed: int) -> None:
    st = dataclasses.replace(OperatorStrategy(), v_cap_mps=0.2, w_cap_radps=0.8)
    X = sample_trajectory(start_6d(), goal_6d(), DT, seed, st).states
    v = np.linalg.norm(np.diff(X.position, axis=0), axis=-1) / DT
    w = np.linalg.norm(so3_log(X.rotation[1:] @ np.swapaxes(X.rotation[:-1], -1, -2)), axis=-1) / DT
    assert v.max() <= 0.2 * 1.001
    assert w.max() <= 0.8 * 1.02  # the cap uses a first-order rotation-vector rate


def test_planar_operator_stays_planar_and_mostly_moves_y_first() -> None:
    start = HandState.from_rotvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], np.zeros(0))
    goal = HandState.from_rotvec([0.3, 0.4, 0.0], [0.0, 0.0, 0.6], np.zeros(0))
    leads = []
    for seed in range(60):
        tr = sample_trajectory(start, goal, DT, seed, PLANAR)
        X = tr.states
        assert np.abs(X.position[:, 2]).max() == 0.0
        assert np.abs(X.rotation[:, 2, :2]).max() < 1e-12  # no roll, no pitch
        leads.append(tr.sample.lead)
        if tr.sample.lead:
            # Halfway through the y motion, x has barely moved (y before x).
            k = int(np.argmax(X.position[:, 1] > 0.2))
            assert X.position[k, 0] < 0.1
    assert 0.6 < np.mean(leads) < 0.95  # lead_probability = 0.8


def test_late_heading_correction() -> None:
    start = HandState.from_rotvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], np.zeros(0))
    goal = HandState.from_rotvec([0.3, 0.4, 0.0], [0.0, 0.0, 0.6], np.zeros(0))
    for seed in range(10):
        X = sample_trajectory(start, goal, DT, seed, PLANAR).states
        heading = np.arctan2(X.rotation[:, 1, 0], X.rotation[:, 0, 0])
        dist = np.linalg.norm(X.position[:, :2] - [0.3, 0.4], axis=-1)
        k = int(np.argmax(dist < 0.5 * 0.5))  # half of the path done
        assert abs(heading[k]) < 0.25 * 0.6 + 0.1  # little of the heading change yet


def test_pauses_and_speed_vary() -> None:
    st = dataclasses.replace(PLANAR, pause_rate=2.0, wander_m=0.0, wander_rad=0.0)
    start = HandState.from_rotvec([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], np.zeros(0))
    goal = HandState.from_rotvec([0.3, 0.4, 0.0], [0.0, 0.0, 0.6], np.zeros(0))
    tr = sample_trajectory(start, goal, DT, 3, st)
    assert tr.sample.pauses
    v = np.linalg.norm(np.diff(tr.states.position, axis=0), axis=-1)
    t0 = tr.sample.reaction_s
    t1 = tr.t_s[-1] - tr.sample.hold_s
    moving = (tr.t_s[1:] > t0 + 0.2) & (tr.t_s[1:] < t1 - 0.2)
    # Still ticks in the middle of the movement: the pauses.
    assert (v[moving] < 1e-9).sum() >= int(0.15 / DT)


def test_stack_pads_with_the_last_state() -> None:
    a = sample_trajectory(start_6d(), goal_6d(), DT, 1)
    b = sample_trajectory(start_6d(), goal_6d(), DT, 2)
    X, lengths = stack([a, b])
    T = max(len(a), len(b))
    assert X.position.shape == (2, T, 3) and X.rotation.shape == (2, T, 3, 3)
    assert list(lengths) == [len(a), len(b)]
    short = int(np.argmin(lengths))
    np.testing.assert_array_equal(X.position[short, -1], X.position[short, lengths[short] - 1])


def test_min_jerk_profile() -> None:
    u = np.linspace(-0.5, 1.5, 41)
    m = min_jerk(u)
    assert m[0] == 0.0 and m[-1] == 1.0
    assert np.all(np.diff(m) >= 0)
    assert min_jerk(np.array([0.5]))[0] == pytest.approx(0.5)


def test_bad_strategy_and_arguments() -> None:
    with pytest.raises(ValueError, match="speed_mps"):
        OperatorStrategy(speed_mps=(0.2, 0.1))
    with pytest.raises(ValueError, match="lead_axes"):
        OperatorStrategy(lead_axes=(3,))
    with pytest.raises(ValueError, match="dt"):
        sample_trajectory(start_6d(), goal_6d(), 0.0, 1)
