"""SO(3)/SE(3) helpers: exp/log round trips and known values, the pi and small-angle
branches, the relative logarithm, diff/integrate on any batch, saturation."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from dsteleop.arbitration import (
    HandState,
    diff,
    integrate,
    log_relative,
    saturate,
    so3_exp,
    so3_log,
)
from dsteleop.arbitration.config import ArbitrationConfig

from .strategies import hand_states

rotvecs = arrays(np.float64, 3, elements=st.floats(-3.1, 3.1, allow_nan=False))
directions = arrays(np.float64, 3, elements=st.floats(-1.0, 1.0, allow_nan=False)).filter(
    lambda v: bool(np.linalg.norm(v) > 0.1)
)


def _angle_between(Ra: NDArray[np.float64], Rb: NDArray[np.float64]) -> float:
    return float(np.linalg.norm(so3_log(Ra @ Rb.T)))


@given(rotvecs)
def test_exp_is_a_rotation(w: NDArray[np.float64]) -> None:
    R = so3_exp(w)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0.999999


@given(rotvecs)
def test_log_inverts_exp_below_pi(w: NDArray[np.float64]) -> None:
    if np.linalg.norm(w) >= np.pi - 1e-6:
        w = w * (np.pi - 1e-3) / np.linalg.norm(w)
    np.testing.assert_allclose(so3_log(so3_exp(w)), w, atol=1e-9)


@given(rotvecs)
def test_exp_of_log_is_identity_everywhere(w: NDArray[np.float64]) -> None:
    R = so3_exp(w)
    np.testing.assert_allclose(so3_exp(so3_log(R)), R, atol=1e-9)


def test_log_at_and_near_pi() -> None:
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([1.0, 2.0, -2.0]) / 3.0):
        for angle in (np.pi, np.pi - 1e-5, np.pi - 5e-4, np.pi - 2e-3):
            w = so3_log(so3_exp(axis * angle))
            assert abs(np.linalg.norm(w) - angle) < 1e-7
            np.testing.assert_allclose(so3_exp(w), so3_exp(axis * angle), atol=1e-9)


def test_log_batched_matches_single() -> None:
    rng = np.random.default_rng(1)
    w = rng.normal(0, 2.0, (50, 3))
    w[0] = [np.pi, 0, 0]
    R = so3_exp(w)
    batched = so3_log(R)
    single = np.array([so3_log(r) for r in R])
    np.testing.assert_allclose(batched, single, atol=1e-12)


@given(rotvecs, st.integers(-2, 2))
def test_full_turns_change_nothing(w: NDArray[np.float64], k: int) -> None:
    n = np.linalg.norm(w)
    if n < 1e-3:
        return
    turned = w + w / n * 2.0 * np.pi * k
    np.testing.assert_allclose(so3_exp(turned), so3_exp(w), atol=1e-9)


@given(hand_states(), hand_states())
def test_integrate_inverts_diff(A: HandState, B: HandState) -> None:
    dt = 0.05
    C = integrate(B, diff(A, B) / dt, dt)
    np.testing.assert_allclose(C.position, A.position, atol=1e-12)
    np.testing.assert_allclose(C.rotation, A.rotation, atol=1e-9)
    np.testing.assert_allclose(C.openness, np.clip(A.openness, 0, 1), atol=1e-12)


@given(arrays(np.float64, 11, elements=st.floats(-50, 50, allow_nan=False)))
def test_saturate_bounds_norms_and_keeps_direction(U: NDArray[np.float64]) -> None:
    cfg = ArbitrationConfig()
    vmax = cfg.v_max(5)
    S = saturate(U, vmax)
    assert np.linalg.norm(S[:3]) <= cfg.v_max_mps * (1 + 1e-12)
    assert np.linalg.norm(S[3:6]) <= cfg.w_max_radps * (1 + 1e-12)
    assert np.all(np.abs(S[6:]) <= cfg.g_max_per_s)
    for sl in (slice(0, 3), slice(3, 6)):
        if np.linalg.norm(U[sl]) > 1e-9:
            cos = S[sl] @ U[sl] / (np.linalg.norm(S[sl]) * np.linalg.norm(U[sl]))
            assert cos > 1 - 1e-9  # a straight line stays straight
    small = U * 1e-4
    np.testing.assert_allclose(saturate(small, vmax), small)  # below the limits: unchanged


def test_diff_uses_rotation_vectors_not_euler() -> None:
    # 170 deg and -170 deg about z are 20 deg apart, not 340.
    A = HandState.from_rotvec([0, 0, 0], [0, 0, np.deg2rad(170)], [])
    B = HandState.from_rotvec([0, 0, 0], [0, 0, np.deg2rad(-170)], [])
    d = diff(A, B)
    assert abs(abs(d[5]) - np.deg2rad(20)) < 1e-9
    assert _angle_between(A.rotation, B.rotation) < np.deg2rad(20.0001)


def _rot_z(theta: float) -> NDArray[np.float64]:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_exp_and_log_known_values() -> None:
    np.testing.assert_array_equal(so3_exp(np.zeros(3)), np.eye(3))
    np.testing.assert_array_equal(so3_log(np.eye(3)), np.zeros(3))
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(so3_exp(np.array([0.0, 0.0, np.pi / 2])), quarter, atol=1e-15)
    np.testing.assert_allclose(so3_log(quarter), [0.0, 0.0, np.pi / 2], rtol=0, atol=1e-15)
    # Half turns about the axes: angle exactly pi, either sign of the axis.
    for k in range(3):
        R = -np.eye(3)
        R[k, k] = 1.0
        w = so3_log(R)
        assert np.isfinite(w).all()
        assert abs(abs(w[k]) - np.pi) < 1e-12
        np.testing.assert_array_equal(np.delete(w, k), 0.0)
    # About z, on both sides of the small-angle series (1e-4 rad) and of the near-pi branch
    # (pi - 1e-3 rad).
    for theta in (1e-12, 1e-8, 1e-6, 9.9e-5, 1.01e-4, 0.5, 2.0, np.pi - 1.01e-3, np.pi - 9.9e-4,
                  np.pi - 1e-6):  # fmt: skip
        w = so3_log(_rot_z(theta))
        np.testing.assert_allclose(w[:2], 0.0, rtol=0, atol=1e-15)
        np.testing.assert_allclose(w[2], theta, rtol=1e-9 if theta < 3 else 0, atol=1e-9)
        np.testing.assert_allclose(so3_exp(np.array([0.0, 0.0, theta])), _rot_z(theta), atol=1e-15)


@given(directions, st.floats(0.0, 2e-4))
def test_tiny_angles_round_trip_to_full_relative_precision(
    axis: NDArray[np.float64], angle: float
) -> None:
    w = axis / np.linalg.norm(axis) * angle
    R = so3_exp(w)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    back = so3_log(R)
    assert np.isfinite(back).all()
    np.testing.assert_allclose(back, w, rtol=1e-9, atol=1e-20)
    np.testing.assert_allclose(log_relative(R, np.eye(3)), w, rtol=1e-9, atol=1e-20)
    np.testing.assert_allclose(log_relative(np.eye(3), R), -w, rtol=1e-9, atol=1e-20)


def norm(x: NDArray[np.float64]) -> float:
    return float(np.linalg.norm(x))


def _near_pi_atol(gap: float) -> float:
    """How well exp(log R) returns R at pi - gap. theta comes from arccos of the trace, whose
    rounding (~1e-16) costs 1e-16 / sin(theta) rad, up to sqrt(1e-16) = 1e-8 at pi itself; just
    outside the near-pi branch (gap >= 1e-3) sin(theta) from the trace costs ~1e-9."""
    return 5e-9 if gap > 1e-6 else 1e-7


@given(directions, st.floats(0.0, 2e-3))
def test_log_at_and_near_pi_is_finite_and_round_trips(
    axis: NDArray[np.float64], gap: float
) -> None:
    axis = axis / np.linalg.norm(axis)
    angle = np.pi - gap
    R = so3_exp(axis * angle)
    w = so3_log(R)
    assert np.isfinite(w).all()
    assert abs(np.linalg.norm(w) - angle) < 1e-7
    np.testing.assert_allclose(so3_exp(w), R, atol=_near_pi_atol(gap))
    if gap > 1e-6:  # the sign of the axis is defined
        np.testing.assert_allclose(w, axis * angle, atol=1e-7)
    else:
        assert abs(abs(w @ axis) - angle) < 1e-7


@given(rotvecs, rotvecs, st.booleans(), st.floats(0.0, 2e-3))
def test_log_relative_is_the_log_of_the_product(
    wa: NDArray[np.float64], wb: NDArray[np.float64], near_pi: bool, gap: float
) -> None:
    Ra = so3_exp(wa)
    if near_pi and np.linalg.norm(wb) > 1e-3:
        # Rb such that Ra Rb^T is a rotation by pi - gap.
        Rb = so3_exp(wb / np.linalg.norm(wb) * (np.pi - gap)).T @ Ra
    else:
        Rb = so3_exp(wb)
    e = log_relative(Ra, Rb)
    assert np.isfinite(e).all() and np.linalg.norm(e) <= np.pi + 1e-12
    np.testing.assert_allclose(so3_exp(e), Ra @ Rb.T, atol=_near_pi_atol(np.pi - norm(e)))
    if np.linalg.norm(e) < np.pi - 1e-6:
        np.testing.assert_allclose(e, so3_log(Ra @ Rb.T), atol=1e-9)


def _near_pi_from(
    R: NDArray[np.float64], rng: np.random.Generator, gap: float
) -> NDArray[np.float64]:
    """Rotations at pi - gap from R (R_b such that log(R R_b^T) has angle pi - gap)."""
    axis = rng.normal(size=(*R.shape[:-2], 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return np.swapaxes(so3_exp(axis * (np.pi - gap)), -1, -2) @ R


def test_so3_log_of_a_batch_is_one_by_one_near_pi_and_tiny() -> None:
    """A batch mixing near-pi, tiny and regular rotations: every row exactly as alone."""
    rng = np.random.default_rng(4)
    R = so3_exp(rng.normal(0, 1, (300, 3)))
    R[::3] = _near_pi_from(np.eye(3), rng, 1e-6)[None]
    R[1::7] = so3_exp(rng.normal(0, 1e-5, (43, 3)))
    batched = so3_log(R)
    single = np.array([so3_log(r) for r in R])
    np.testing.assert_array_equal(batched, single)
    assert so3_log(R.reshape(30, 10, 3, 3)).shape == (30, 10, 3)
    np.testing.assert_array_equal(so3_log(R.reshape(30, 10, 3, 3)).reshape(300, 3), batched)
    # The relative log of a batch, near pi and tiny, against one by one, and broadcast.
    Rb = _near_pi_from(R, rng, 2e-4)
    Rb[1::5] = so3_exp(rng.normal(0, 1e-5, (60, 3))) @ R[1::5]
    rel = log_relative(R, Rb)
    # (One pair alone sums the trace in another order: equal to ~1e-9 near pi, see below.)
    np.testing.assert_allclose(
        rel, np.array([log_relative(a, b) for a, b in zip(R, Rb)]), rtol=0, atol=1e-9
    )
    np.testing.assert_array_equal(rel[:7], log_relative(R[:7], Rb[:7]))  # any batch of 2+
    np.testing.assert_allclose(np.linalg.norm(rel[::5], axis=-1), np.pi - 2e-4, atol=1e-9)
    one = so3_exp(np.array([0.3, -0.2, 0.1]))
    np.testing.assert_allclose(
        log_relative(R, one), np.array([log_relative(a, one) for a in R]), rtol=0, atol=1e-9
    )


def test_log_relative_of_one_pair_is_bitwise_its_batched_row() -> None:
    rng = np.random.default_rng(7)
    Ra = so3_exp(rng.normal(0, 2, (200, 3)))
    Rb = _near_pi_from(Ra, rng, 1.01e-3)
    batched = log_relative(Ra, Rb)
    single = np.array([log_relative(a, b) for a, b in zip(Ra, Rb)])
    np.testing.assert_array_equal(batched, single)


def test_holding_still_is_exactly_zero() -> None:
    """diff of a state with itself, integrating zero, saturating zero: exact, finite."""
    rng = np.random.default_rng(5)
    A = HandState(
        rng.uniform(-1, 1, (4, 3)), so3_exp(rng.normal(0, 2, (4, 3))), rng.uniform(0, 1, (4, 2))
    )
    np.testing.assert_array_equal(diff(A, A), 0.0)
    np.testing.assert_array_equal(log_relative(A.rotation, A.rotation), 0.0)
    still = integrate(A, np.zeros((4, 8)), 0.05)
    np.testing.assert_array_equal(still.position, A.position)
    np.testing.assert_array_equal(still.rotation, A.rotation)
    np.testing.assert_array_equal(still.openness, A.openness)
    vmax = ArbitrationConfig().v_max(2)
    np.testing.assert_array_equal(saturate(np.zeros((4, 8)), vmax), 0.0)


@given(hand_states(n_fingers=2), hand_states(n_fingers=2))
def test_diff_and_integrate_on_nested_and_broadcast_batches(A: HandState, B: HandState) -> None:
    """A (3, 4) batch, and one state broadcast against it: each entry as computed alone."""
    rng = np.random.default_rng(6)
    shape = (3, 4)
    As = HandState(
        A.position + rng.normal(0, 0.2, (*shape, 3)),
        so3_exp(rng.normal(0, 1.0, (*shape, 3))) @ A.rotation,
        np.clip(A.openness + rng.normal(0, 0.2, (*shape, 2)), 0, 1),
    )
    d = diff(As, B)
    U = rng.normal(0, 1.0, (*shape, 8))
    X = integrate(As, U, 0.05)
    Xb = integrate(B, U, 0.05)  # one state, a batch of actions
    assert d.shape == (*shape, 8) and X.rotation.shape == (*shape, 3, 3)
    assert Xb.position.shape == (*shape, 3)
    for idx in np.ndindex(*shape):
        one = HandState(As.position[idx], As.rotation[idx], As.openness[idx])
        # one state alone sums the relative rotation's trace in another order (above)
        np.testing.assert_allclose(d[idx], diff(one, B), rtol=0, atol=1e-9)
        Xi = integrate(one, U[idx], 0.05)
        np.testing.assert_array_equal(X.position[idx], Xi.position)
        np.testing.assert_array_equal(X.rotation[idx], Xi.rotation)
        np.testing.assert_array_equal(X.openness[idx], Xi.openness)
        np.testing.assert_array_equal(Xb.rotation[idx], integrate(B, U[idx], 0.05).rotation)
