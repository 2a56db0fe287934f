"""Arbitration core: eq (1)-(8) properties, the paper's scenarios, the one kernel on any batch
(a batch of N is N single steps), its edge cases, eq (2) on the reference X_ref, the filter
state, config, history and what importing it loads.

There is one implementation of the maths (`arbitration/`); nothing here restates it. The
checks are properties of that implementation: batched against single, known values,
invariants (bounds, round trips) and the documented semantics of the moving windows.
"""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    ArbitrationStep,
    FilterState,
    HandState,
    InvalidConfig,
    Mode,
    OperatorHistory,
    RowModes,
    diff,
    integrate,
    log_relative,
    make_arbiter,
    saturate,
    so3_exp,
)
from dsteleop.arbitration.allocation import (
    ds_alpha,
    expected_allocation,
    expected_speed_change,
    standard_alpha,
    unit_directions,
    willingness,
)
from dsteleop.arbitration.modes.ds import Windows
from dsteleop.errors import ConfigError

from .strategies import (
    arbitration_inputs,
    hand_states,
    input_from_states,
    random_input,
    random_state,
    stack_inputs,
    states_of,
    with_states,
)

Array = NDArray[np.float64]
DT = 1.0 / 30.0
F = 4


def state(p: list[float], rv: list[float], g: float | list[float] = 1.0) -> HandState:
    gg = [g] * F if isinstance(g, float) else g
    return HandState.from_rotvec(p, rv, gg)


def assert_step_matches(
    single: ArbitrationStep,
    batched: ArbitrationStep,
    index: tuple[int, ...] = (),
    atol: float = 0.0,
) -> None:
    """Every output of `single` equals row `index` of `batched`: to the last bit by default,
    since the kernel runs the same compiled code for every row whatever the batch."""
    for name in STEP_ARRAYS:
        np.testing.assert_allclose(
            getattr(single, name), getattr(batched, name)[index], rtol=0, atol=atol, err_msg=name
        )
    for name in ("position", "rotation", "openness"):
        np.testing.assert_allclose(
            getattr(single.X_next, name),
            getattr(batched.X_next, name)[index],
            rtol=0,
            atol=atol,
            err_msg=f"X_next.{name}",
        )


def at(k: int, batch: tuple[int, ...]) -> tuple[int, ...]:
    """The index of the k-th state of a row-major batch."""
    return tuple(int(i) for i in np.unravel_index(k, batch))


def assert_states_close(A: HandState, B: HandState, atol: float = 1e-12) -> None:
    np.testing.assert_allclose(A.position, B.position, rtol=0, atol=atol)
    np.testing.assert_allclose(A.rotation, B.rotation, rtol=0, atol=atol)
    np.testing.assert_allclose(A.openness, B.openness, rtol=0, atol=atol)


# --- eq (3)-(8) properties -------------------------------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
@given(inp=arbitration_inputs(big=True))
def test_alpha_in_unit_interval_and_everything_finite(mode: Mode, inp: ArbitrationInput) -> None:
    arb = make_arbiter(mode)
    _, r = arb.step(arb.initial_state(6 + 5), inp)
    for name in ("alpha", "P_human", "P_robot", "B", "psi_human", "psi_robot", "U_out"):
        assert np.isfinite(getattr(r, name)).all(), name
    assert ((r.alpha >= 0) & (r.alpha <= 1)).all()
    assert ((r.B >= 0) & (r.B <= 1 + 1e-12)).all()
    assert ((r.P_human >= 0) & (r.P_human <= 1)).all()
    assert r.X_next.is_finite()


@given(
    st.lists(st.floats(0, 1), min_size=11, max_size=11),
    st.lists(st.floats(0, 1), min_size=11, max_size=11),
)
def test_b_zero_gives_p_human_and_b_one_gives_p_robot(pr: list[float], ph: list[float]) -> None:
    P_r, P_h = np.array(pr), np.array(ph)
    np.testing.assert_allclose(ds_alpha(P_r, P_h, np.zeros(11)), P_h, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ds_alpha(P_r, P_h, np.ones(11)), P_r, rtol=0, atol=1e-12)


@given(inp=arbitration_inputs(), alpha_mode=st.sampled_from(list(Mode)))
def test_operator_acting_like_the_policy_gets_exactly_that_action(
    inp: ArbitrationInput, alpha_mode: Mode
) -> None:
    """Operator's target == robot's goal, equal gains and limits: U_out == U_h == U_r."""
    cfg = ArbitrationConfig()
    # The hand moved from the robot's pose exactly as the robot's policy would move it.
    U_policy = saturate(cfg.gains(5) * diff(inp.X_goal, inp.X_current), cfg.v_max(5))
    hand_now = integrate(inp.X_current, U_policy, inp.dt)
    moved = ArbitrationInput(
        X_human=hand_now,
        X_human_prev=inp.X_current,
        X_human_start=inp.X_human_start,
        X_current=inp.X_current,
        X_prev=inp.X_prev,
        X_start=inp.X_start,
        X_goal=inp.X_goal,
        dt=inp.dt,
    )
    arb = make_arbiter(alpha_mode, cfg)
    _, r = arb.step(arb.initial_state(11), moved)
    # Openness clipped at [0, 1] while integrating changes nothing when it stays inside.
    inside = np.all(
        (inp.X_current.openness + U_policy[6:] * inp.dt >= 0)
        & (inp.X_current.openness + U_policy[6:] * inp.dt <= 1)
    )
    if inside and np.linalg.norm(U_policy[3:6]) * inp.dt < 3.0:
        np.testing.assert_allclose(r.U_human, r.U_robot, atol=1e-9)
        np.testing.assert_allclose(r.U_out, r.U_robot, atol=1e-9)


@given(
    st.floats(-3.0, 3.0, allow_nan=False),
    st.integers(-2, 2),
)
def test_rotation_by_two_pi_changes_nothing(theta: float, k: int) -> None:
    G = state([0.5, 0.0, 0.3], [0, 0, 0.2])
    base = state([0.4, 0.1, 0.3], [0, 0, theta])
    turned = state([0.4, 0.1, 0.3], [0, 0, theta + 2 * np.pi * k])
    inp_a = ArbitrationInput(
        X_human=base,
        X_human_prev=base,
        X_human_start=base,
        X_current=base,
        X_prev=base,
        X_start=base,
        X_goal=G,
        dt=DT,
    )
    inp_b = ArbitrationInput(
        X_human=turned,
        X_human_prev=turned,
        X_human_start=turned,
        X_current=turned,
        X_prev=turned,
        X_start=turned,
        X_goal=G,
        dt=DT,
    )
    arb = make_arbiter(Mode.DS)
    _, ra = arb.step(arb.initial_state(6 + F), inp_a)
    _, rb = arb.step(arb.initial_state(6 + F), inp_b)
    for name in ("alpha", "P_robot", "B", "U_out"):
        np.testing.assert_allclose(getattr(ra, name), getattr(rb, name), atol=1e-9)


def test_p_is_one_at_the_goal_and_falls_monotonically_with_distance() -> None:
    cfg = ArbitrationConfig()
    eps = cfg.alloc_floor(F)
    start = state([0.0, 0.0, 0.0], [0, 0, 0], 1.0)
    goal = state([0.3, -0.2, 0.1], [0.3, -0.4, 0.5], 0.0)
    d_gs = diff(goal, start)
    assert np.allclose(expected_allocation(diff(goal, goal), d_gs, eps, cfg.kappa), 1.0)
    # Move away from the goal along every dimension at once: P falls in each.
    prev = np.ones(6 + F)
    for s in np.linspace(0.05, 1.5, 30):
        d = s * np.array([0.3, -0.2, 0.1, 0.6, -0.7, 0.8, 0.5, 0.5, 0.5, 0.5])
        P = expected_allocation(d, d_gs, eps, cfg.kappa)
        assert np.all(P < prev)
        prev = P
    assert np.all(prev[:3] < 0.05)  # 1.5x the start distance: 1 - erf(1.5)


def test_rotation_allocation_is_a_normalised_von_mises() -> None:
    kappa = 4.0
    e = np.linspace(-np.pi, np.pi, 41)
    # Dimension-first: 10 dimensions, 41 samples.
    d = np.zeros((10, 41))
    d[5] = e
    P = expected_allocation(d, np.ones((10, 1)), np.full(10, 1e-3), kappa)[5]
    raw = np.exp(kappa * np.cos(e)) / (2 * np.pi * np.i0(kappa))
    np.testing.assert_allclose(P, raw / raw.max())


@pytest.mark.parametrize("batch", [(7,), (3, 4)])
def test_allocation_is_dimension_first(batch: tuple[int, ...]) -> None:
    """Every eq (3)-(8) function on (D, ...) arrays equals the same call on each (D,) column."""
    rng = np.random.default_rng(12)
    cfg = ArbitrationConfig()
    D = 6 + F
    eps, v_max = cfg.alloc_floor(F), cfg.v_max(F)
    step, offset = cfg.still_step(F, 1 / 30), cfg.still_offset(F)
    d1, d2, d3 = (rng.normal(0.0, 0.3, (D, *batch)) for _ in range(3))
    d3[:, (0,) * len(batch)] = 0.0  # one column below every threshold
    U = rng.normal(0.0, 0.5, (D, *batch))
    hist = rng.normal(0.0, 0.3, D)
    P = expected_allocation(d1, d2, eps, cfg.kappa)
    u = unit_directions(d3, offset)
    psi = expected_speed_change(U, v_max, d1, d3, hist, step, offset)
    B = willingness(d1, d2, cfg.p, cfg.q, cfg.b, cfg.psi_robot_floor)
    a = ds_alpha(P, u, B)
    s = standard_alpha(d1[:3], d2[:3], d3[:3], cfg.alloc_floor_m)
    assert P.shape == u.shape == psi.shape == B.shape == a.shape == (D, *batch)
    assert s.shape == batch
    np.testing.assert_array_equal(u[:, (0,) * len(batch)], 0.0)
    for idx in np.ndindex(*batch):
        col: tuple[slice | int, ...] = (slice(None), *idx)
        np.testing.assert_allclose(P[col], expected_allocation(d1[col], d2[col], eps, cfg.kappa))
        np.testing.assert_allclose(u[col], unit_directions(d3[col], offset))
        np.testing.assert_allclose(
            psi[col], expected_speed_change(U[col], v_max, d1[col], d3[col], hist, step, offset)
        )
        np.testing.assert_allclose(
            B[col], willingness(d1[col], d2[col], cfg.p, cfg.q, cfg.b, cfg.psi_robot_floor)
        )
        np.testing.assert_allclose(a[col], ds_alpha(P[col], u[col], B[col]))
        np.testing.assert_allclose(
            s[idx], standard_alpha(d1[:3][col], d2[:3][col], d3[:3][col], cfg.alloc_floor_m)
        )


def test_standard_mode_gives_one_alpha_for_all_dims() -> None:
    rng = np.random.default_rng(3)
    arb = make_arbiter(Mode.S)
    for _ in range(20):
        s = [
            state(
                list(rng.normal(0, 0.3, 3)), list(rng.normal(0, 1, 3)), list(rng.uniform(0, 1, F))
            )
            for _ in range(7)
        ]
        _, r = arb.step(arb.initial_state(6 + F), input_from_states(s, DT))
        assert np.ptp(r.alpha) == 0.0
        p_goal, p_cur, p_start = s[6].position, s[3].position, s[5].position
        from scipy.special import erf

        expected = 1 - erf(np.abs(p_goal - p_cur).sum() / np.abs(p_goal - p_start).sum())
        assert r.alpha[0] == pytest.approx(expected)


def test_manual_and_autonomous_are_the_two_baselines() -> None:
    s = [state([0.1 * i, 0.05, 0.2], [0, 0.1 * i, 0], 0.5) for i in range(7)]
    inp = input_from_states(s, DT)
    man, aut = make_arbiter("manual"), make_arbiter("autonomous")
    _, rm = man.step(man.initial_state(10), inp)
    _, ra = aut.step(aut.initial_state(10), inp)
    np.testing.assert_array_equal(rm.alpha, 0.0)
    np.testing.assert_array_equal(ra.alpha, 1.0)
    np.testing.assert_allclose(rm.U_out, rm.U_human)
    np.testing.assert_allclose(ra.U_out, ra.U_robot)


def test_willingness_shape_matches_fig4() -> None:
    """B = 0 at psi_h = 0, B = 1 slightly below psi_r, B -> 0 for very fast psi_h."""
    p, q, b = 4.0, 6.0, 1.0
    psi_r = np.full(2000, 0.8)
    x = np.linspace(0, 20, 2000)
    B = willingness(x, psi_r, p, q, b, 0.05)
    assert B[0] == 0.0
    peak = x[np.argmax(B)]
    assert 0.3 * 0.8 < peak < 0.8
    assert B.max() == pytest.approx(1.0, abs=1e-4)
    assert B[-1] < 1e-3
    assert np.all(np.diff(B[: np.argmax(B)]) > 0) and np.all(np.diff(B[np.argmax(B) + 1 :]) < 0)
    # The |psi_robot| ~ 0 rule: finite, and an operator who does not change speed is unwilling.
    assert willingness(np.array([0.0]), np.array([0.0]), p, q, b, 0.05)[0] == 0.0
    assert np.isfinite(willingness(np.array([0.3]), np.array([0.0]), p, q, b, 0.05)).all()


# --- the paper's scenarios (Fig. 3-6 narrative) inside a closed loop ------------------


def run_loop(
    mode: Mode,
    hand_path: list[HandState],
    goal: HandState,
    history: OperatorHistory | None = None,
    segment_start: HandState | None = None,
) -> list[ArbitrationStep]:
    """Close the loop on the arbitration alone: X_next becomes the next X_current."""
    cfg = ArbitrationConfig()
    arb = make_arbiter(mode, cfg)
    X = hand_path[0]
    start = hand_start = hand_path[0] if segment_start is None else segment_start
    prev, hand_prev = X, hand_path[0]
    fs = arb.initial_state(6 + F)
    hist = None if history is None else history.term(F, cfg.still_offset(F))
    out = []
    for hand in hand_path[1:]:
        fs, r = arb.step(
            fs,
            ArbitrationInput(
                X_human=hand,
                X_human_prev=hand_prev,
                X_human_start=hand_start,
                X_current=X,
                X_prev=prev,
                X_start=start,
                X_goal=goal,
                dt=DT,
                history_term=hist,
            ),
        )
        prev, X, hand_prev = X, r.X_next, hand
        out.append(r)
    return out


def test_operator_moving_along_y_only_keeps_alpha_x_low_and_raises_alpha_y() -> None:
    goal = state([0.6, 0.3, 0.3], [np.pi, 0, 0])
    # The operator moves only along y, at 0.1 m/s, to the goal's y.
    path = [state([0.4, min(0.1 * DT * k, 0.3), 0.3], [np.pi, 0, 0]) for k in range(120)]
    steps = run_loop(Mode.DS, path, goal)
    ax = np.array([r.alpha[0] for r in steps])
    ay = np.array([r.alpha[1] for r in steps])
    s_alpha = np.array([r.alpha[0] for r in run_loop(Mode.S, path, goal)])
    assert ax[-1] < 0.3
    assert ay[-1] > 0.8 and ay[-1] > ay[5] + 0.5
    assert ax[-1] < s_alpha[-1] - 0.2  # S pulls x along with y; DS does not


def test_operator_holding_still_near_the_goal_gets_control_back() -> None:
    start = state([0.4, 0.0, 0.3], [np.pi, 0, 0])
    goal = state([0.6, 0.2, 0.3], [np.pi, 0, 0.3])
    near = state([0.595, 0.198, 0.3], [np.pi, 0, 0.25])
    # Previous attempts went from the same start to the same goal (eq 6, last term).
    history = OperatorHistory().add(start, goal).add(start, goal)
    # The segment began at `start`; the operator has come near the goal and holds still.
    path = [near] * 60
    steps = run_loop(Mode.DS, path, goal, history, segment_start=start)
    last = steps[-1]
    assert np.all(last.B[:6] < 0.05)
    np.testing.assert_allclose(last.alpha[:6], last.P_human[:6], atol=0.05)


def test_ds_b_starts_at_one() -> None:
    s = state([0.4, 0.0, 0.3], [np.pi, 0, 0])
    goal = state([0.6, 0.2, 0.3], [np.pi, 0, 0.3])
    arb = make_arbiter(Mode.DS, ArbitrationConfig(window=5))
    fs = arb.initial_state(6 + F)
    assert len(fs.B_rows) == len(fs.alpha_rows) == 5 and fs.count == 0
    for row in fs.B_rows:
        np.testing.assert_array_equal(row, 1.0)
    _, r = arb.step(
        fs,
        ArbitrationInput(
            X_human=s,
            X_human_prev=s,
            X_human_start=s,
            X_current=s,
            X_prev=s,
            X_start=s,
            X_goal=goal,
            dt=DT,
        ),
    )
    # One raw sample of 5 in the window: B >= 4/5.
    assert np.all(r.B >= 0.8 - 1e-12)


def test_window_one_is_eq8_unfiltered() -> None:
    rng = np.random.default_rng(5)
    s = [
        state(list(rng.normal(0, 0.2, 3)), list(rng.normal(0, 1, 3)), list(rng.uniform(0, 1, F)))
        for _ in range(7)
    ]
    inp = input_from_states(s, DT)
    arb = make_arbiter(Mode.DS, ArbitrationConfig(window=1))
    _, r = arb.step(arb.initial_state(6 + F), inp)
    np.testing.assert_allclose(r.alpha, np.clip((r.P_robot - r.P_human) * r.B + r.P_human, 0, 1))


@given(inp=arbitration_inputs(), window=st.integers(1, 4))
@settings(max_examples=40)
def test_ds_windows_are_moving_averages(inp: ArbitrationInput, window: int) -> None:
    """The same tick repeated: B's window (starting full of ones) and alpha's window (eq 8 on
    the filtered B, averaged over the ticks seen) are the means of their last W samples."""
    raw_arb = make_arbiter(Mode.DS, ArbitrationConfig(window=1))
    _, raw = raw_arb.step(raw_arb.initial_state(11), inp)  # window 1: the raw B and eq (8)
    arb = make_arbiter(Mode.DS, ArbitrationConfig(window=window))
    fs = arb.initial_state(11)
    alphas: list[Array] = []
    for k in range(1, 2 * window + 2):
        fs, r = arb.step(fs, inp)
        n = min(k, window)
        B_expected = ((window - n) * 1.0 + n * raw.B) / window
        np.testing.assert_allclose(r.B, B_expected, rtol=0, atol=1e-12)
        alphas.append(ds_alpha(raw.P_robot, raw.P_human, B_expected))
        np.testing.assert_allclose(r.alpha, np.mean(alphas[-n:], 0), rtol=0, atol=1e-12)
        assert fs.count == k
    np.testing.assert_allclose(r.alpha, raw.alpha, rtol=0, atol=1e-12)  # the windows are full


# --- one kernel: a batch of N is N single steps -----------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
@given(
    data=st.data(),
    batch=st.sampled_from([(), (1,), (7,), (3, 4)]),
    n_fingers=st.sampled_from([0, 5]),
    history=st.booleans(),
    dt=st.sampled_from([1 / 30, 0.01, 0.1]),
)
@settings(max_examples=30)
def test_batched_equals_single_steps(
    mode: Mode,
    data: st.DataObject,
    batch: tuple[int, ...],
    n_fingers: int,
    history: bool,
    dt: float,
) -> None:
    D = 6 + n_fingers
    h = np.linspace(-0.4, 0.4, D) if history else None
    inputs = [
        input_from_states(states_of(data.draw(arbitration_inputs(n_fingers))), dt, h)
        for _ in range(math.prod(batch))
    ]
    arb = make_arbiter(mode, ArbitrationConfig(window=2))
    fs_b = arb.initial_state(D, batch)
    fs_s = [arb.initial_state(D) for _ in inputs]
    stacked = stack_inputs(inputs, batch)
    for _tick in range(3):  # through the DS windows
        fs_b, batched = arb.step(fs_b, stacked)
        assert batched.alpha.shape == (*batch, D)
        assert batched.X_next.rotation.shape == (*batch, 3, 3)
        for k, inp in enumerate(inputs):
            fs_s[k], single = arb.step(fs_s[k], inp)
            assert_step_matches(single, batched, at(k, batch))
        assert fs_b.count == fs_s[0].count


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("n_fingers", [0, 1, 4])
@pytest.mark.parametrize("batch", [(), (1,), (7,), (3, 4), (257,)])
def test_shapes_fingers_and_history(mode: Mode, n_fingers: int, batch: tuple[int, ...]) -> None:
    """Fresh random inputs every tick, with and without a history term, through the windows."""
    rng = np.random.default_rng(n_fingers + 7 * len(batch))
    D = 6 + n_fingers
    M = math.prod(batch)
    for history in (False, True):
        h = rng.normal(0.0, 0.3, D) if history else None
        arb = make_arbiter(mode, ArbitrationConfig(window=2))
        fs_b = arb.initial_state(D, batch)
        checked = range(0, M, max(1, M // 20))  # every row of the small batches
        fs_s = {k: arb.initial_state(D) for k in checked}
        for _tick in range(3):
            inputs = [
                with_states(random_input(rng, (), n_fingers), history_term=h) for _ in range(M)
            ]
            fs_b, batched = arb.step(fs_b, stack_inputs(inputs, batch))
            for k in checked:
                fs_s[k], single = arb.step(fs_s[k], inputs[k])
                assert_step_matches(single, batched, at(k, batch))


def test_ds_filter_state_over_many_steps_matches_batched() -> None:
    rng = np.random.default_rng(11)
    arb = make_arbiter(Mode.DS, ArbitrationConfig(window=3))
    n = 4
    fs_b = arb.initial_state(11, (n,))
    fs_s = [arb.initial_state(11) for _ in range(n)]
    for _ in range(10):
        inputs = []
        for _k in range(n):
            s = [
                HandState(rng.normal(0, 0.3, 3), so3_exp(rng.normal(0, 1, 3)), rng.uniform(0, 1, 5))
                for _ in range(7)
            ]
            inputs.append(input_from_states(s, DT))
        fs_b, rb = arb.step(fs_b, stack_inputs(inputs))
        for k in range(n):
            fs_s[k], rs = arb.step(fs_s[k], inputs[k])
            np.testing.assert_allclose(rs.alpha, rb.alpha[k], atol=1e-12)
            np.testing.assert_allclose(rs.B, rb.B[k], atol=1e-12)


def test_a_batch_that_mixes_modes_equals_one_batch_per_mode() -> None:
    """The study steps every mode of a trajectory in one batch (`RowModes`): each row gets
    exactly what a batch of its own mode gives, over ticks (the DS windows included)."""
    rng = np.random.default_rng(8)
    cfg = ArbitrationConfig(window=3)
    modes = [Mode.S, Mode.DS, Mode.MANUAL, Mode.AUTONOMOUS, Mode.DS, Mode.S]
    rows = RowModes.of(modes)
    mixed = make_arbiter(Mode.DS, cfg)
    fs_mixed = mixed.initial_state(10, (len(modes),))
    alone = {m: make_arbiter(m, cfg) for m in set(modes)}
    fs_alone = [alone[m].initial_state(10) for m in modes]
    for _ in range(6):
        inputs = [
            input_from_states([random_state(rng, (), 4) for _ in range(7)], 0.05) for _ in modes
        ]
        fs_mixed, rb = mixed.step(fs_mixed, stack_inputs(inputs), rows)
        for i, m in enumerate(modes):
            fs_alone[i], r = alone[m].step(fs_alone[i], inputs[i])
            assert_step_matches(r, rb, (i,))
    kept = rows.select(np.array([True, False, True, False, False, True]))
    assert [m for m, _ in kept.groups()] == [Mode.S, Mode.MANUAL]
    with pytest.raises(ConfigError, match="modes for"):
        mixed.step(fs_mixed, stack_inputs(inputs), kept)


def test_a_mixed_batch_keeps_windows_for_its_ds_rows_only() -> None:
    """In a batch that mixes modes, DS's windows are its own rows' (a tick copies those, not
    the whole batch's); selecting rows maps them into the kept batch, and the kept rows step
    as a batch of their own mode does."""
    rng = np.random.default_rng(12)
    cfg = ArbitrationConfig(window=3)
    modes = [Mode.S, Mode.DS, Mode.MANUAL, Mode.DS, Mode.DS, Mode.S]
    mixed = make_arbiter(Mode.DS, cfg)
    alone = make_arbiter(Mode.DS, cfg)
    rows = RowModes.of(modes)
    fs_mixed = mixed.initial_state(10, (len(modes),))
    ds_rows = [i for i, m in enumerate(modes) if m is Mode.DS]
    fs_alone = [alone.initial_state(10) for _ in ds_rows]

    def tick(fs: FilterState, which: RowModes, n: int) -> tuple[FilterState, ArbitrationStep]:
        inputs = [input_from_states([random_state(rng, (), 4) for _ in range(7)], 0.05)
                  for _ in range(n)]  # fmt: skip
        fs, step = mixed.step(fs, stack_inputs(inputs), which)
        ds = [i for i, c in enumerate(which.codes) if which.modes[c] is Mode.DS]
        for k, i in enumerate(ds):
            fs_alone[k], r = alone.step(fs_alone[k], inputs[i])
            assert_step_matches(r, step, (i,))
        return fs, step

    for _ in range(4):
        fs_mixed, _ = tick(fs_mixed, rows, len(modes))
    own = fs_mixed.of(Mode.DS)
    np.testing.assert_array_equal(own.rows, ds_rows)
    assert fs_mixed.alpha_window.shape == fs_mixed.B_window.shape == (3, len(ds_rows), 10)
    keep = np.array([True, True, False, False, True, True])  # drops DS row 3
    part = fs_mixed.select(keep)
    np.testing.assert_array_equal(part.of(Mode.DS).rows, [1, 2])
    np.testing.assert_array_equal(part.alpha_window, fs_mixed.alpha_window[:, [0, 2]])
    del fs_alone[1]
    for _ in range(3):
        part, _ = tick(part, rows.select(keep), int(keep.sum()))


@pytest.mark.parametrize("mode", list(Mode))
def test_closed_loop_single_and_batched_agree(mode: Mode) -> None:
    """X_next fed back as X_current and as the reference X_ref for 40 ticks, with a history
    term: three single loops equal one batched loop of three."""
    rng = np.random.default_rng(6)
    cfg = ArbitrationConfig(window=4, max_lead_m=0.01, max_lead_rad=0.05)
    arb = make_arbiter(mode, cfg)
    h = rng.normal(0.0, 0.3, 10)
    goals = [random_state(rng, (), 4) for _ in range(3)]
    hands = [[random_state(rng, (), 4) for _ in range(41)] for _ in range(3)]
    start = [random_state(rng, (), 4) for _ in range(3)]
    X, Xp, ref = list(start), list(start), list(start)
    fs = [arb.initial_state(10) for _ in range(3)]
    fsb = arb.initial_state(10, (3,))
    Xb = Xbp = refb = stack_inputs([input_from_states([s] * 7, 0.05) for s in start]).X_current
    for k in range(40):
        inputs = [
            ArbitrationInput(
                X_human=hands[i][k + 1],
                X_human_prev=hands[i][k],
                X_human_start=hands[i][0],
                X_current=X[i],
                X_prev=Xp[i],
                X_start=start[i],
                X_goal=goals[i],
                dt=0.05,
                history_term=h,
                X_ref=ref[i],
            )
            for i in range(3)
        ]
        results = []
        for i in range(3):
            fs[i], r = arb.step(fs[i], inputs[i])
            # The achieved state lags the command: half way from X_current to X_next.
            lagged = HandState(
                0.5 * (X[i].position + r.X_next.position), r.X_next.rotation, r.X_next.openness
            )
            Xp[i], X[i], ref[i] = X[i], lagged, r.X_next
            results.append(r)
        binp = with_states(stack_inputs(inputs), X_current=Xb, X_prev=Xbp, X_ref=refb)
        fsb, rb = arb.step(fsb, binp)
        lagged_b = HandState(
            0.5 * (Xb.position + rb.X_next.position), rb.X_next.rotation, rb.X_next.openness
        )
        Xbp, Xb, refb = Xb, lagged_b, rb.X_next
        for i in range(3):
            assert_step_matches(results[i], rb, (i,))


@pytest.mark.parametrize("mode", list(Mode))
def test_inputs_broadcast_between_themselves(mode: Mode) -> None:
    """An unbatched goal and start with batched hands equal explicitly repeated copies."""
    rng = np.random.default_rng(5)
    inp = random_input(rng, (6,), 5, history=True)
    one = random_input(rng, (), 5)
    inp = with_states(inp, X_goal=one.X_goal, X_start=one.X_start, X_human_start=one.X_human_start)

    def tiled(X: HandState) -> HandState:
        return HandState(
            np.broadcast_to(X.position, (6, 3)).copy(),
            np.broadcast_to(X.rotation, (6, 3, 3)).copy(),
            np.broadcast_to(X.openness, (6, 5)).copy(),
        )

    full = with_states(
        inp,
        X_goal=tiled(one.X_goal),
        X_start=tiled(one.X_start),
        X_human_start=tiled(one.X_human_start),
    )
    arb = make_arbiter(mode)
    fs_a = fs_b = arb.initial_state(11, (6,))
    for _ in range(2):
        fs_a, ra = arb.step(fs_a, inp)
        fs_b, rb = arb.step(fs_b, full)
        for i in range(6):
            assert_step_matches(
                ArbitrationStep(
                    **{n: getattr(ra, n)[i] for n in STEP_ARRAYS}, X_next=ra.X_next.take(i)
                ),
                rb,
                (i,),
            )


def test_no_fingers_works_for_planar_studies() -> None:
    s = [HandState.from_rotvec([0.1 * i, 0.0, 0.0], [0, 0, 0.1 * i], []) for i in range(7)]
    for mode in Mode:
        arb = make_arbiter(mode)
        _, r = arb.step(arb.initial_state(6), input_from_states(s, DT))
        assert r.alpha.shape == (6,) and np.isfinite(r.U_out).all()
        _, rb = arb.step(arb.initial_state(6, (3,)), stack_inputs([input_from_states(s, DT)] * 3))
        np.testing.assert_allclose(rb.alpha[1], r.alpha, atol=1e-12)


# --- edge cases: holding still, tiny angles, rotations at and near pi ---------------------


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("batch", [(), (64,)])
def test_holding_still_gives_finite_psi_and_b(mode: Mode, batch: tuple[int, ...]) -> None:
    """No motion (every difference 0), motion below the still thresholds (unit directions 0)
    and tiny rotations
    (the series branches): psi and B finite, with their known values."""
    rng = np.random.default_rng(2)
    cfg = ArbitrationConfig(window=1)  # B and alpha unfiltered
    arb = make_arbiter(mode, cfg)
    D = 11
    inp = random_input(rng, batch, 5)
    H, C = inp.X_human, inp.X_current
    v_max = cfg.v_max(5)

    # Nobody moved and nobody has moved since the start.
    _, r = arb.step(
        arb.initial_state(D, batch),
        with_states(inp, X_human_prev=H, X_human_start=H, X_prev=C, X_start=C),
    )
    for name in STEP_ARRAYS:
        assert np.isfinite(getattr(r, name)).all(), name
    np.testing.assert_array_equal(r.U_human, 0.0)
    np.testing.assert_array_equal(r.psi_human, 0.0)
    np.testing.assert_array_equal(r.B, 0.0)  # psi_human = 0: unwilling (p > 1)
    np.testing.assert_allclose(r.psi_robot, r.U_robot / v_max, rtol=0, atol=1e-15)

    # The hand moved by less than the still thresholds in every group, through tiny angles.
    dp = rng.normal(0.0, 2e-5, H.position.shape)
    w = rng.normal(0.0, 2e-5, H.position.shape)
    dg = rng.normal(0.0, 5e-5, H.openness.shape)
    tiny = HandState(H.position - dp, so3_exp(w) @ H.rotation, H.openness - dg)
    _, r = arb.step(
        arb.initial_state(D, batch), with_states(inp, X_human_prev=tiny, X_human_start=tiny)
    )
    for name in STEP_ARRAYS:
        assert np.isfinite(getattr(r, name)).all(), name
    # diff(H, tiny) = (dp, log(exp(-w)), dg): the hand's own motion over dt.
    np.testing.assert_allclose(r.U_human[..., :3], dp / inp.dt, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(r.U_human[..., 3:6], -w / inp.dt, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(r.U_human[..., 6:], dg / inp.dt, rtol=1e-9, atol=1e-15)
    # Unit directions vanish below the thresholds: psi is the normalised action alone.
    np.testing.assert_allclose(r.psi_human, r.U_human / v_max, rtol=0, atol=1e-15)
    assert ((r.B >= 0.0) & (r.B <= 1.0)).all()

    # Everyone at the goal: full allocation to both, no robot action.
    G = inp.X_goal
    _, r = arb.step(
        arb.initial_state(D, batch),
        with_states(inp, X_current=G, X_prev=G, X_human=G, X_human_prev=G),
    )
    for name in STEP_ARRAYS:
        assert np.isfinite(getattr(r, name)).all(), name
    np.testing.assert_array_equal(r.P_robot, 1.0)
    np.testing.assert_array_equal(r.P_human, 1.0)
    np.testing.assert_array_equal(r.U_robot, 0.0)
    np.testing.assert_array_equal(r.U_out, 0.0)
    assert_states_close(r.X_next, G, atol=0.0)


def _near_pi_from(R: Array, rng: np.random.Generator, gap: float) -> tuple[Array, Array]:
    """(R_b, axis) with log(R R_b^T) = axis * (pi - gap), axis a random unit vector."""
    axis = rng.normal(size=(*R.shape[:-2], 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return np.swapaxes(so3_exp(axis * (np.pi - gap)), -1, -2) @ R, axis


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("batch", [(), (5,), (400,)])
@pytest.mark.parametrize("gap", [0.0, 5e-6, 2e-4, 2e-3])
def test_rotations_at_and_near_pi(mode: Mode, batch: tuple[int, ...], gap: float) -> None:
    """Relative rotations at and near pi (in a batch, only some rows): finite, the actions
    along the rotation's axis, and each row equal to its single step."""
    rng = np.random.default_rng(3)
    inp = random_input(rng, batch, 4)
    H, C, G = inp.X_human, inp.X_current, inp.X_goal
    R_hp, axis_h = _near_pi_from(H.rotation, rng, gap)
    R_c, axis_r = _near_pi_from(G.rotation, rng, gap)
    R_p, _ = _near_pi_from(R_c, rng, gap)
    flip = with_states(
        inp,
        X_human_prev=HandState(H.position, R_hp, H.openness),
        X_current=HandState(C.position, R_c, C.openness),
        X_prev=HandState(C.position, R_p, C.openness),
    )
    if batch == (400,):  # every third row near pi, the others as they were
        keep = np.arange(400) % 3 != 0
        mixed = {}
        for name in ("X_human_prev", "X_current", "X_prev"):
            a, b = getattr(flip, name), getattr(inp, name)
            mixed[name] = HandState(
                a.position, np.where(keep[:, None, None], b.rotation, a.rotation), a.openness
            )
        flip = with_states(flip, **mixed)
    cfg = ArbitrationConfig()
    arb = make_arbiter(mode, cfg)
    _, r = arb.step(arb.initial_state(10, batch), flip)
    for name in STEP_ARRAYS:
        assert np.isfinite(getattr(r, name)).all(), name
    assert r.X_next.is_finite()
    assert ((r.alpha >= 0) & (r.alpha <= 1)).all()
    rows = np.arange(400) % 3 == 0 if batch == (400,) else np.ones(batch, dtype=bool)
    # K_r (pi - gap) and (pi - gap) / dt exceed w_max: both actions saturate along the axis
    # (at exactly pi the axis's sign is arbitrary).
    for U, axis in ((r.U_robot, axis_r), (r.U_human, axis_h)):
        w = U[..., 3:6][rows]
        np.testing.assert_allclose(np.linalg.norm(w, axis=-1), cfg.w_max_radps, rtol=1e-12)
        cos = (w * axis[rows]).sum(-1) / cfg.w_max_radps
        if gap > 1e-6:
            np.testing.assert_allclose(cos, 1.0, rtol=0, atol=1e-9)
        else:
            np.testing.assert_allclose(np.abs(cos), 1.0, rtol=0, atol=1e-7)
    # Each row against its own single step (rows take the near-pi branch alone).
    if batch:
        for i in range(0, batch[0], max(1, batch[0] // 25)):
            one = input_from_states([X.take(i) for X in states_of(flip)], flip.dt)
            _, single = arb.step(arb.initial_state(10), one)
            assert_step_matches(single, r, (i,))


# --- eq (2): the reference X_ref, bounded by max_lead --------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
@given(inp=arbitration_inputs())
@settings(max_examples=40)
def test_without_a_reference_eq2_integrates_from_x_current(
    mode: Mode, inp: ArbitrationInput
) -> None:
    arb = make_arbiter(mode)
    _, r = arb.step(arb.initial_state(11), inp)
    assert_states_close(r.X_next, integrate(inp.X_current, r.U_out, inp.dt))
    # X_current passed as the reference (a separate object) is the same tick.
    same = HandState(
        inp.X_current.position.copy(),
        inp.X_current.rotation.copy(),
        inp.X_current.openness.copy(),
    )
    _, r2 = arb.step(arb.initial_state(11), with_states(inp, X_ref=same))
    assert_step_matches(r, r2, ())


@pytest.mark.parametrize("mode", list(Mode))
@given(inp=arbitration_inputs(), offset=hand_states(), scale=st.floats(0.0, 1.0))
@settings(max_examples=40)
def test_eq2_integrates_from_the_reference(
    mode: Mode, inp: ArbitrationInput, offset: HandState, scale: float
) -> None:
    """Within the lead bound X_next = integrate(X_ref, U_out, dt); X_ref changes nothing else."""
    C = inp.X_current
    X_ref = HandState(
        C.position + 0.01 * scale * offset.position,
        so3_exp(0.05 * scale * offset.rotvec()) @ C.rotation,
        np.clip(C.openness + 0.1 * scale * (offset.openness - 0.5), 0.0, 1.0),
    )
    cfg = ArbitrationConfig(max_lead_m=10.0, max_lead_rad=3.5)  # never binds
    arb = make_arbiter(mode, cfg)
    _, plain = arb.step(arb.initial_state(11), inp)
    _, r = arb.step(arb.initial_state(11), with_states(inp, X_ref=X_ref))
    assert_states_close(r.X_next, integrate(X_ref, r.U_out, inp.dt))
    for name in STEP_ARRAYS:
        np.testing.assert_array_equal(getattr(r, name), getattr(plain, name), err_msg=name)


@pytest.mark.parametrize("mode", list(Mode))
@given(
    inp=arbitration_inputs(),
    X_ref=hand_states(),
    leads=st.sampled_from([(0.03, 0.25), (1e-3, 1e-2), (0.3, 2.0)]),
)
@settings(max_examples=40)
def test_x_next_stays_within_max_lead_of_x_current(
    mode: Mode, inp: ArbitrationInput, X_ref: HandState, leads: tuple[float, float]
) -> None:
    """Wherever the reference is, X_next is integrate(X_ref, U_out, dt) pulled back towards
    X_current to within max_lead_m and max_lead_rad, along the same line and the same axis."""
    lead_m, lead_rad = leads
    cfg = ArbitrationConfig(max_lead_m=lead_m, max_lead_rad=lead_rad)
    arb = make_arbiter(mode, cfg)
    C = inp.X_current
    _, r = arb.step(arb.initial_state(11), with_states(inp, X_ref=X_ref))
    free = integrate(X_ref, r.U_out, inp.dt)
    X = r.X_next
    # Translation: at most lead_m away, on the segment towards the unbounded point.
    dp, dp_free = X.position - C.position, free.position - C.position
    n, n_free = np.linalg.norm(dp), np.linalg.norm(dp_free)
    assert n <= lead_m * (1 + 1e-12)
    assert n == pytest.approx(min(n_free, lead_m), rel=1e-12, abs=1e-15)
    if n_free > 1e-6:
        np.testing.assert_allclose(dp / n, dp_free / n_free, rtol=0, atol=1e-9)
    # Rotation: at most lead_rad from X_current, about the same axis.
    e, e_free = log_relative(X.rotation, C.rotation), log_relative(free.rotation, C.rotation)
    a, a_free = np.linalg.norm(e), np.linalg.norm(e_free)
    assert a <= lead_rad + 1e-9
    assert a == pytest.approx(min(a_free, lead_rad), rel=1e-9, abs=1e-12)
    if 1e-6 < a_free < np.pi - 1e-6:
        np.testing.assert_allclose(e / a, e_free / a_free, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(X.openness, free.openness)  # fingers are not bounded
    # Without a reference the bound holds too, when it is tighter than one saturated tick.
    _, r0 = arb.step(arb.initial_state(11), inp)
    assert np.linalg.norm(r0.X_next.position - C.position) <= lead_m * (1 + 1e-12)
    assert np.linalg.norm(log_relative(r0.X_next.rotation, C.rotation)) <= lead_rad + 1e-9


def test_a_blocked_robot_winds_the_reference_up_to_the_bound_only() -> None:
    """The robot does not move (blocked); the hand keeps moving; X_next fed back as X_ref
    leads X_current by exactly max_lead_m in the end, along the hand's motion."""
    cfg = ArbitrationConfig()
    arb = make_arbiter(Mode.MANUAL, cfg)
    C = state([0.4, 0.0, 0.3], [np.pi, 0, 0])
    goal = state([0.6, 0.2, 0.3], [np.pi, 0, 0.3])
    fs, ref = arb.initial_state(10), C
    hand_prev = C
    for k in range(1, 120):
        hand = state([0.4 + 0.1 * DT * k, 0.0, 0.3], [np.pi, 0, 0])
        fs, r = arb.step(
            fs,
            ArbitrationInput(
                X_human=hand,
                X_human_prev=hand_prev,
                X_human_start=C,
                X_current=C,
                X_prev=C,
                X_start=C,
                X_goal=goal,
                dt=DT,
                X_ref=ref,
            ),
        )
        hand_prev, ref = hand, r.X_next
        assert np.linalg.norm(ref.position - C.position) <= cfg.max_lead_m * (1 + 1e-12)
    np.testing.assert_allclose(ref.position - C.position, [cfg.max_lead_m, 0, 0], atol=1e-12)


# --- the filter state ---------------------------------------------------------------------


@pytest.mark.parametrize("batch", [(), (8,)])
def test_step_leaves_its_inputs_and_old_state_alone(batch: tuple[int, ...]) -> None:
    rng = np.random.default_rng(7)
    inp = random_input(rng, batch, 5, history=True)
    inp = with_states(inp, X_ref=random_state(rng, batch, 5))
    states = [*states_of(inp), inp.X_ref]
    copies = [[a.copy() for a in vars(X).values()] for X in states if X is not None]
    assert inp.history_term is not None
    history = inp.history_term.copy()
    arb = make_arbiter(Mode.DS)
    fs0 = arb.initial_state(11, batch)
    fs1, r1 = arb.step(fs0, inp)
    for row in fs0.B_rows:
        np.testing.assert_array_equal(row, 1.0)
    for row in fs0.alpha_rows:
        np.testing.assert_array_equal(row, 0.0)
    assert fs0.count == 0 and fs1.count == 1 and fs1.batch == batch
    for X, saved in zip([X for X in states if X is not None], copies):
        for a, b in zip(vars(X).values(), saved):
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(inp.history_term, history)
    # Writing into a result changes no state; stepping a state leaves it as it was (the new
    # state shares the untouched window rows), so an old state can be stepped again.
    windows = [r.copy() for r in (*fs1.alpha_rows, *fs1.B_rows)]
    for name in STEP_ARRAYS:
        getattr(r1, name)[...] = -1.0
    for a in vars(r1.X_next).values():
        a[...] = -1.0
    fs2, r2 = arb.step(fs1, inp)
    assert np.all(r2.alpha >= 0.0)
    for row, before in zip((*fs1.alpha_rows, *fs1.B_rows), windows):
        np.testing.assert_array_equal(row, before)
    fs2b, r2b = arb.step(fs1, inp)
    assert_step_matches(r2, r2b, ())
    for a, b in zip(fs2.B_rows, fs2b.B_rows):
        np.testing.assert_array_equal(a, b)
    assert r2.alpha.shape == (*batch, 11) and r2.X_next.rotation.shape == (*batch, 3, 3)


@pytest.mark.parametrize("batch", [(), (6,), (2, 3)])
def test_filter_state_rebuilt_from_its_rows_steps_like_the_original(
    batch: tuple[int, ...],
) -> None:
    rng = np.random.default_rng(9)
    arb = make_arbiter(Mode.DS)
    fs = arb.initial_state(11, batch)
    for _ in range(3):
        fs, _ = arb.step(fs, random_input(rng, batch, 5))
    M = math.prod(batch)
    assert len(fs.alpha_rows) == len(fs.B_rows) == 5
    assert all(r.shape == (M, 11) for r in (*fs.alpha_rows, *fs.B_rows))
    assert fs.alpha_window.shape == fs.B_window.shape == (5, M, 11)
    copy = FilterState(
        fs.batch, fs.dims, (("DS", Windows(fs.alpha_window.copy(), fs.B_window.copy(), fs.count)),)
    )
    inp = random_input(rng, batch, 5)
    (a, ra), (b, rb) = arb.step(fs, inp), arb.step(copy, inp)
    assert_step_matches(ra, rb, ())
    for x, y in zip((*a.alpha_rows, *a.B_rows), (*b.alpha_rows, *b.B_rows)):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("mode", list(Mode))
def test_filter_state_select_keeps_the_selected_rows(mode: Mode) -> None:
    rng = np.random.default_rng(10)
    arb = make_arbiter(mode, ArbitrationConfig(window=3))
    fs = arb.initial_state(11, (6,))
    for _ in range(4):
        fs, _ = arb.step(fs, random_input(rng, (6,), 5))
    keep = np.array([True, False, True, True, False, False])
    part = fs.select(keep)
    assert part.count == fs.count and part.batch == (3,)
    for x, y in zip((*part.alpha_rows, *part.B_rows), (*fs.alpha_rows, *fs.B_rows)):
        np.testing.assert_array_equal(x, y[keep])
    # Stepping the selected rows equals stepping all and keeping those rows.
    inp = random_input(rng, (6,), 5, history=True)
    kept = input_from_states([X.take(keep) for X in states_of(inp)], inp.dt, inp.history_term)
    p1, r_part = arb.step(part, kept)
    a1, r_all = arb.step(fs, inp)
    for k, i in enumerate(np.flatnonzero(keep)):
        single = ArbitrationStep(
            **{n: getattr(r_part, n)[k] for n in STEP_ARRAYS}, X_next=r_part.X_next.take(k)
        )
        assert_step_matches(single, r_all, (int(i),))
    for x, y in zip((*p1.alpha_rows, *p1.B_rows), (*a1.alpha_rows, *a1.B_rows)):
        np.testing.assert_allclose(x, y[keep], rtol=0, atol=1e-12)
    # Selecting nothing and everything.
    assert fs.select(np.zeros(6, dtype=bool)).batch == (0,)
    assert fs.select(np.ones(6, dtype=bool)).batch == (6,)


@pytest.mark.parametrize("mode", list(Mode))
def test_a_filter_state_of_another_batch_or_size_raises(mode: Mode) -> None:
    """The filter state's batch must be the inputs' batch (no broadcasting of a state)."""
    rng = np.random.default_rng(8)
    arb = make_arbiter(mode)
    cases = [
        (arb.initial_state(11, (3,)), random_input(rng, (), 5)),  # bigger state, single tick
        (arb.initial_state(11), random_input(rng, (2,), 5)),  # single state, batched tick
        (arb.initial_state(11, (12,)), random_input(rng, (3, 4), 5)),  # same size, other shape
        (arb.initial_state(11, (4,)).select(np.ones(4, bool)), random_input(rng, (5,), 5)),
        (arb.initial_state(10), random_input(rng, (), 5)),  # 10 dims for an 11-dim tick
        (arb.initial_state(11, (2,)), random_input(rng, (2,), 0)),
    ]
    for fs, inp in cases:
        with pytest.raises(ConfigError, match="filter state"):
            arb.step(fs, inp)
    # ... and the error is a ValueError for callers that catch those.
    with pytest.raises(ValueError, match="filter state"):
        arb.step(*cases[0])


# --- config, modes, history -------------------------------------------------------------


def test_config_json_round_trip_and_validation() -> None:
    cfg = ArbitrationConfig(kappa=6.0, window=3)
    assert ArbitrationConfig.from_json(cfg.to_json()) == cfg
    with pytest.raises(InvalidConfig, match="kappa"):
        ArbitrationConfig(kappa=-1.0)
    with pytest.raises(InvalidConfig, match="p must be > 1"):
        ArbitrationConfig(p=1.0)
    with pytest.raises(InvalidConfig, match="window"):
        ArbitrationConfig(window=2.5)  # type: ignore[arg-type]  # deliberately not an int
    with pytest.raises(InvalidConfig, match="v_max_mps"):
        ArbitrationConfig(v_max_mps=float("nan"))
    with pytest.raises(InvalidConfig, match="max_lead_m"):
        ArbitrationConfig(max_lead_m=0.0)
    with pytest.raises(InvalidConfig, match="unknown"):
        ArbitrationConfig.from_dict({"kapa": 3.0})
    assert InvalidConfig is ConfigError


def test_mode_parse() -> None:
    assert Mode.parse("ds") is Mode.DS and Mode.parse("Manual") is Mode.MANUAL
    with pytest.raises(ConfigError, match="unknown mode"):
        Mode.parse("turbo")
    with pytest.raises(ValueError, match="unknown mode"):
        make_arbiter("turbo")


def test_operator_history_term_and_round_trip() -> None:
    cfg = ArbitrationConfig()
    h = OperatorHistory()
    np.testing.assert_array_equal(h.term(F, cfg.still_offset(F)), 0.0)
    a = state([0, 0, 0], [0, 0, 0], 1.0)
    b = state([0.3, 0.4, 0], [0, 0, 0.5], 0.0)
    h = h.add(a, b)
    term = h.term(F, cfg.still_offset(F))
    np.testing.assert_allclose(term[:3], [0.6, 0.8, 0.0])
    np.testing.assert_allclose(term[3:6], [0, 0, 1.0])
    np.testing.assert_allclose(term[6:], -0.5)
    # A second attempt along -y: the mean of the two unit directions.
    h2 = h.add(a, state([0.0, -0.2, 0.0], [0, 0, 0], 1.0))
    np.testing.assert_allclose(h2.term(F, cfg.still_offset(F))[:3], [0.3, -0.1, 0.0])
    again = OperatorHistory.from_dict(json.loads(json.dumps(h.to_dict())))
    assert again == h
    with pytest.raises(ValueError):
        OperatorHistory.from_dict({"schema": "other"})


# --- what importing loads -----------------------------------------------------------------

HEAVY = ("pybullet", "viser", "cv2", "mediapipe")


def _heavy_modules_after(code: str) -> list[str]:
    probe = f"{code}\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return [m for m in out.stdout.strip().split(",") if m]


def test_arbitration_imports_no_heavy_modules() -> None:
    code = (
        "import importlib, pkgutil, dsteleop.arbitration as a\n"
        "for m in pkgutil.iter_modules(a.__path__):\n"
        "    importlib.import_module('dsteleop.arbitration.' + m.name)\n"
    )
    assert _heavy_modules_after(code) == []


@pytest.mark.parametrize(
    "module",
    ["dsteleop.app.loop.tick", "dsteleop.app.loop.runner", "dsteleop.app.ports", "session"],
)
def test_loop_ports_and_session_import_no_heavy_modules(module: str) -> None:
    """The pure tick, the runner, the ports and every session module load no PyBullet,
    Viser, OpenCV or MediaPipe (each in a fresh interpreter)."""
    if module == "session":
        code = (
            "import importlib, pkgutil, dsteleop.app.session as s\n"
            "names = [m.name for m in pkgutil.iter_modules(s.__path__)]\n"
            "assert {'schema', 'reader', 'writer', 'trace', 'video'} <= set(names), names\n"
            "for n in names:\n"
            "    importlib.import_module('dsteleop.app.session.' + n)\n"
        )
    else:
        code = f"import {module}"
    assert _heavy_modules_after(code) == []


# --- what X_human is under the rate mapping, and the leaky reference (issue 31) -------------


def _pushing(cfg: ArbitrationConfig, seconds: float) -> tuple[list[float], list[float], Array]:
    """A hand that keeps moving in +x at 0.1 m/s against a robot held by alpha = 1 (the
    autonomous rule, the goal where the robot is): the hand's lead over the robot |X_human -
    X_current| and the lead of what eq (4)-(6) read (the hand, or its leaky reference), per
    tick, and P(H) of x per tick."""
    arb = make_arbiter(Mode.AUTONOMOUS, cfg)
    X = state([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    fs = arb.initial_state(6 + F)
    hand_prev = X
    hand_lead, read_lead, P_x = [], [], []
    for k in range(1, round(seconds / DT) + 1):
        hand = state([0.1 * k * DT, 0.0, 0.0], [0.0, 0.0, 0.0])
        fs, r = arb.step(
            fs,
            ArbitrationInput(
                X_human=hand, X_human_prev=hand_prev, X_human_start=X, X_current=X,
                X_prev=X, X_start=X, X_goal=X, dt=DT,
            ),
        )  # fmt: skip
        np.testing.assert_array_equal(r.X_next.position, X.position)  # the robot is held
        read = hand if fs.reference is None else fs.reference
        hand_lead.append(float(np.linalg.norm(hand.position - X.position)))
        read_lead.append(float(np.linalg.norm(read.position - X.position)))
        P_x.append(float(r.P_human[0]))
        hand_prev = hand
    return hand_lead, read_lead, np.array(P_x)


def test_under_the_rate_mapping_x_human_drifts_from_a_robot_that_resists() -> None:
    """docs/METHOD.md §2: the hand's mapped pose integrates its motion, so against a robot
    held in place its distance from the robot grows linearly with time (0.1 m/s here), and
    P(H) (eq 4) reads how long the person pushed, not where they want the robot."""
    hand_lead, read_lead, P_x = _pushing(ArbitrationConfig(), 6.0)
    assert read_lead == hand_lead  # "hand": eq (4)-(6) read the hand itself
    t = DT * np.arange(1, len(hand_lead) + 1)
    np.testing.assert_allclose(hand_lead, 0.1 * t, rtol=1e-9)
    assert hand_lead[-1] == pytest.approx(0.6) and np.all(np.diff(hand_lead) > 0)
    assert np.all(np.diff(P_x) <= 0) and P_x[-1] < 1e-6  # P(H) only falls, to nothing


def test_the_leaky_reference_stays_within_v_tau_of_the_robot() -> None:
    """The same push, "leaky": the reference's lead settles at v dt e / (1 - e) (e =
    exp(-dt / tau)), about v tau, instead of growing."""
    for tau in (0.5, 1.0):
        cfg = ArbitrationConfig(human_reference="leaky", human_leak_s=tau)
        hand_lead, read_lead, P_x = _pushing(cfg, 6.0)
        e = math.exp(-DT / tau)
        limit = 0.1 * DT * e / (1.0 - e)
        assert limit == pytest.approx(0.1 * (tau - DT / 2), rel=1e-3)  # about v tau
        assert max(read_lead) <= limit * (1 + 1e-9)
        assert read_lead[-1] == pytest.approx(limit, rel=5e-3)  # within e^-6 after 6 s
        assert hand_lead[-1] == pytest.approx(0.6)  # the hand itself drifted on
        # P(H) of x no longer falls with the time pushed: in the last second it stays far
        # above the hand's reading (which is ~0 by then).
        late = P_x[-round(1.0 / DT) :]
        assert late.min() > 100 * _pushing(ArbitrationConfig(), 6.0)[2][-1]


def test_the_leaky_reference_is_the_hand_when_the_robot_follows_the_hand() -> None:
    """Manual mode, the robot exactly at the hand every tick (rotations and fingers moving
    too, under the velocity limits): the leaky reference has no lead to decay, so every
    output equals "hand"'s."""
    path = [
        state([0.02 * np.sin(0.2 * k), 0.05 * k * DT, 0.0], [0.2 * np.sin(0.1 * k), 0.0, 0.01 * k],
              0.5 + 0.3 * np.sin(0.15 * k))
        for k in range(40)
    ]  # fmt: skip
    goal = state([0.3, 0.2, 0.1], [0.0, 0.5, 0.0])
    out = {}
    for ref in ("hand", "leaky"):
        arb = make_arbiter(Mode.MANUAL, ArbitrationConfig(human_reference=ref))
        fs = arb.initial_state(6 + F)
        steps = []
        for prev, hand in itertools.pairwise(path):
            fs, r = arb.step(
                fs,
                ArbitrationInput(
                    X_human=hand, X_human_prev=prev, X_human_start=path[0], X_current=hand,
                    X_prev=prev, X_start=path[0], X_goal=goal, dt=DT,
                ),
            )  # fmt: skip
            steps.append(r)
            if ref == "leaky":
                assert fs.reference is not None
                assert_states_close(fs.reference, hand, atol=1e-12)
        out[ref] = steps
    for a, b in zip(out["hand"], out["leaky"], strict=True):
        assert_step_matches(a, b, atol=1e-9)


def test_the_leaky_reference_is_per_row_state_restarted_with_the_segment() -> None:
    """A batch keeps one reference per row (`FilterState.reference`), `select` keeps the
    rows', and a fresh state (a segment's start) restarts it at X_start."""
    rng = np.random.default_rng(2)
    cfg = ArbitrationConfig(human_reference="leaky")
    arb = make_arbiter(Mode.DS, cfg)
    inp = random_input(rng, (4,), F)
    fs, _ = arb.step(arb.initial_state(6 + F, (4,)), inp)
    assert fs.reference is not None and fs.reference.batch == (4,)
    keep = np.array([True, False, True, True])
    kept = fs.select(keep)
    assert kept.reference is not None
    np.testing.assert_array_equal(kept.reference.position, fs.reference.position[keep])
    fs2, _ = arb.step(fs, inp)
    fresh, _ = arb.step(arb.initial_state(6 + F, (4,)), inp)
    assert fs2.reference is not None and fresh.reference is not None
    assert not np.allclose(fs2.reference.position, fs.reference.position)  # carried on
    np.testing.assert_array_equal(fresh.reference.position, fs.reference.position)  # restarted
    assert arb.initial_state(6 + F, (4,)).reference is None


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"human_reference": "foo"}, "human_reference must be one of hand, leaky"),
        ({"human_leak_s": 0.0}, "human_leak_s must be finite and > 0"),
    ],
)
def test_a_bad_human_reference_is_a_config_error(changes: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        ArbitrationConfig().replace(**changes)
    cfg = ArbitrationConfig(human_reference="leaky", human_leak_s=0.5)
    assert ArbitrationConfig.from_json(cfg.to_json()) == cfg
