"""Arbitration core: eq (1)-(8) properties, the paper's scenarios, config and history."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    ArbitrationStep,
    HandState,
    InvalidConfig,
    Mode,
    OperatorHistory,
    diff,
    make_arbiter,
    saturate,
    so3_exp,
)
from dsteleop.arbitration.allocation import ds_alpha, expected_allocation, willingness

from .strategies import arbitration_inputs, input_from_states, stack_inputs

DT = 1.0 / 30.0
F = 4


def state(p: list[float], rv: list[float], g: float | list[float] = 1.0) -> HandState:
    gg = [g] * F if isinstance(g, float) else g
    return HandState.from_rotvec(p, rv, gg)


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
    from dsteleop.arbitration import integrate

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
    inp_a = ArbitrationInput(base, base, base, base, base, base, G, DT)
    inp_b = ArbitrationInput(turned, turned, turned, turned, turned, turned, G, DT)
    arb = make_arbiter(Mode.DS)
    _, ra = arb.step(arb.initial_state(6 + F), inp_a)
    _, rb = arb.step(arb.initial_state(6 + F), inp_b)
    for name in ("alpha", "P_robot", "B", "U_out"):
        np.testing.assert_allclose(getattr(ra, name), getattr(rb, name), atol=1e-9)


def test_p_is_one_at_the_goal_and_falls_monotonically_with_distance() -> None:
    cfg = ArbitrationConfig()
    eps = cfg.eps(F)
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
    d = np.zeros((41, 10))
    d[:, 5] = e
    P = expected_allocation(d, np.ones(10), np.full(10, 1e-3), kappa)[:, 5]
    raw = np.exp(kappa * np.cos(e)) / (2 * np.pi * np.i0(kappa))
    np.testing.assert_allclose(P, raw / raw.max())


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
    hist = None if history is None else history.term(F, cfg.eps(F))
    out = []
    for hand in hand_path[1:]:
        fs, r = arb.step(
            fs, ArbitrationInput(hand, hand_prev, hand_start, X, prev, start, goal, DT, hist)
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
    np.testing.assert_array_equal(fs.B_buf, 1.0)
    _, r = arb.step(fs, ArbitrationInput(s, s, s, s, s, s, goal, DT))
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


# --- batched vs single, and the scalar fast path -------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
@given(st.lists(arbitration_inputs(), min_size=2, max_size=6))
def test_batched_equals_single_steps(mode: Mode, inputs: list[ArbitrationInput]) -> None:
    dt = inputs[0].dt
    inputs = [
        input_from_states(
            [
                getattr(i, n)
                for n in (
                    "X_human",
                    "X_human_prev",
                    "X_human_start",
                    "X_current",
                    "X_prev",
                    "X_start",
                    "X_goal",
                )
            ],
            dt,
        )
        for i in inputs
    ]
    arb = make_arbiter(mode)
    _, batched = arb.step(arb.initial_state(11, (len(inputs),)), stack_inputs(inputs))
    for k, inp in enumerate(inputs):
        _, single = arb.step(arb.initial_state(11), inp)
        for name in STEP_ARRAYS:
            np.testing.assert_allclose(
                getattr(single, name), getattr(batched, name)[k], rtol=1e-9, atol=1e-9, err_msg=name
            )
        np.testing.assert_allclose(single.X_next.position, batched.X_next.position[k], atol=1e-9)
        np.testing.assert_allclose(single.X_next.rotation, batched.X_next.rotation[k], atol=1e-9)
        np.testing.assert_allclose(single.X_next.openness, batched.X_next.openness[k], atol=1e-9)


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
            np.testing.assert_allclose(rs.alpha, rb.alpha[k], atol=1e-9)
            np.testing.assert_allclose(rs.B, rb.B[k], atol=1e-9)


def test_no_fingers_works_for_planar_studies() -> None:
    s = [HandState.from_rotvec([0.1 * i, 0.0, 0.0], [0, 0, 0.1 * i], []) for i in range(7)]
    for mode in Mode:
        arb = make_arbiter(mode)
        _, r = arb.step(arb.initial_state(6), input_from_states(s, DT))
        assert r.alpha.shape == (6,) and np.isfinite(r.U_out).all()
        _, rb = arb.step(arb.initial_state(6, (3,)), stack_inputs([input_from_states(s, DT)] * 3))
        np.testing.assert_allclose(rb.alpha[1], r.alpha, atol=1e-9)


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
    with pytest.raises(InvalidConfig, match="unknown"):
        ArbitrationConfig.from_dict({"kapa": 3.0})


def test_mode_parse() -> None:
    assert Mode.parse("ds") is Mode.DS and Mode.parse("Manual") is Mode.MANUAL
    with pytest.raises(ValueError, match="unknown mode"):
        Mode.parse("turbo")


def test_operator_history_term_and_round_trip() -> None:
    cfg = ArbitrationConfig()
    h = OperatorHistory()
    np.testing.assert_array_equal(h.term(F, cfg.eps(F)), 0.0)
    a = state([0, 0, 0], [0, 0, 0], 1.0)
    b = state([0.3, 0.4, 0], [0, 0, 0.5], 0.0)
    h = h.add(a, b)
    term = h.term(F, cfg.eps(F))
    np.testing.assert_allclose(term[:3], [0.6, 0.8, 0.0])
    np.testing.assert_allclose(term[3:6], [0, 0, 1.0])
    np.testing.assert_allclose(term[6:], -0.5)
    again = OperatorHistory.from_dict(json.loads(json.dumps(h.to_dict())))
    assert again == h
    with pytest.raises(ValueError):
        OperatorHistory.from_dict({"schema": "other"})


def test_arbitration_imports_no_heavy_modules() -> None:
    code = (
        "import importlib, pkgutil, sys, dsteleop.arbitration as a\n"
        "for m in pkgutil.iter_modules(a.__path__):\n"
        "    importlib.import_module('dsteleop.arbitration.' + m.name)\n"
        "bad = [m for m in ('pybullet', 'viser', 'cv2', 'mediapipe') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
