"""SO(3)/SE(3) helpers: exp/log round trips, the pi branch, diff/integrate, saturation."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray

from dsteleop.arbitration import HandState, diff, integrate, saturate, so3_exp, so3_log
from dsteleop.arbitration.config import ArbitrationConfig

from .strategies import hand_states

rotvecs = arrays(np.float64, 3, elements=st.floats(-3.1, 3.1, allow_nan=False))


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
