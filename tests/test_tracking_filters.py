"""One Euro filters on R^n and SO(3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.arbitration import so3_exp, so3_log
from dsteleop.tracking import HandFilterConfig, OneEuroConfig, OneEuroFilter, SO3OneEuroFilter
from dsteleop.tracking.filters import smoothing_factor

DT = 1.0 / 30.0


def run(flt: OneEuroFilter, xs: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([flt(x, k * DT) for k, x in enumerate(xs)])


def test_first_sample_passes_and_constant_stays_constant() -> None:
    flt = OneEuroFilter(OneEuroConfig(1.0, 10.0))
    out = run(flt, np.tile([0.1, -0.2, 0.5], (50, 1)))
    assert np.array_equal(out, np.tile([0.1, -0.2, 0.5], (50, 1)))


def test_smoothing_factor_is_a_first_order_low_pass() -> None:
    # a = 1 / (1 + tau / dt), tau = 1 / (2 pi f)
    assert smoothing_factor(1.0, DT) == pytest.approx(1.0 / (1.0 + 30.0 / (2.0 * math.pi)))


def test_still_hand_jitter_is_reduced() -> None:
    """sigma = 3 mm white noise on a still 3-D position, default position filter.

    At rest the cutoff is min_cutoff = 1 Hz (plus beta times the small noise-driven speed
    estimate), an exponential average with a = 0.17 at 30 Hz whose output std is
    sqrt(a / (2 - a)) = 0.31 of the input's; the derivative noise raises the cutoff a
    little, so require below 0.5.
    """
    rng = np.random.default_rng(0)
    raw = 0.003 * rng.normal(size=(600, 3))
    out = run(OneEuroFilter(HandFilterConfig().position), raw)[60:]
    step_raw = np.median(np.linalg.norm(np.diff(raw[60:], axis=0), axis=1))
    step_out = np.median(np.linalg.norm(np.diff(out, axis=0), axis=1))
    assert out.std(0).mean() < 0.5 * raw[60:].std(0).mean()
    assert step_out < 0.3 * step_raw


def test_fast_moves_lag_less_than_slow_ones() -> None:
    """The One Euro property: the steady-state lag of a ramp shrinks as speed grows.

    On a ramp x = v t the lag (error / v) of an exponential filter is tau = 1 / (2 pi f):
    160 ms at 1 Hz. With beta = 20 Hz per m/s the cutoff at 0.5 m/s is 11 Hz, lag ~ 15 ms
    plus the one-sample delay of the discrete filter (a ~ 0.7): below 40 ms.
    """
    lags = {}
    for v in (0.02, 0.5):
        t = np.arange(90) * DT
        xs = np.stack([v * t, 0 * t, 0 * t], -1)
        out = run(OneEuroFilter(HandFilterConfig().position), xs)
        lags[v] = float((xs[-1, 0] - out[-1, 0]) / v)
    assert lags[0.5] < 0.04
    assert lags[0.02] > 2.0 * lags[0.5]


def test_per_component_cutoffs_keep_channels_independent() -> None:
    cfg = OneEuroConfig(1.0, 5.0)
    xs = np.zeros((40, 2))
    xs[10:, 0] = 1.0  # a step in channel 0 only
    joint = run(OneEuroFilter(cfg, per_component=True), xs)
    alone = run(OneEuroFilter(cfg), xs[:, :1])
    assert np.allclose(joint[:, 0], alone[:, 0])
    assert np.all(joint[:, 1] == 0.0)


def test_non_increasing_time_keeps_the_estimate() -> None:
    flt = OneEuroFilter(OneEuroConfig(1.0, 0.0))
    flt(np.array([0.0]), 1.0)
    first = flt(np.array([1.0]), 1.1)
    assert np.array_equal(flt(np.array([5.0]), 1.1), first)
    assert np.array_equal(flt(np.array([5.0]), 1.0), first)


@pytest.mark.parametrize("start", [0.0, 2.9])  # 2.9 rad: the angle crosses pi on the way
def test_so3_filter_equals_scalar_filter_about_a_fixed_axis(start: float) -> None:
    """About one axis, SO(3) is the circle: the geodesic filter must match the scalar One
    Euro filter on the unwrapped angle, including across pi, where rotation vectors and
    Euler angles jump by 2 pi."""
    cfg = OneEuroConfig(1.0, 2.0)
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    t = np.arange(60) * DT
    angle = start + 0.8 * np.sin(2.0 * t) + 0.3 * t
    R0 = so3_exp(np.array([0.3, -0.2, 0.1]))
    rot = SO3OneEuroFilter(cfg)
    lin = OneEuroFilter(cfg)
    for k in range(len(t)):
        R = rot(so3_exp(angle[k] * axis) @ R0, t[k])
        a = lin(np.array([angle[k]]), t[k])[0]
        err = so3_log(R @ np.linalg.inv(so3_exp(a * axis) @ R0))
        assert np.linalg.norm(err) < 1e-9


def test_so3_filter_output_stays_a_rotation() -> None:
    rng = np.random.default_rng(1)
    flt = SO3OneEuroFilter(OneEuroConfig(1.0, 2.0))
    for k in range(300):
        R = flt(so3_exp(rng.normal(0, 1.5, 3)), k * DT)
        assert R.T @ R == pytest.approx(np.eye(3), abs=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


def test_reset_restarts_from_the_next_sample() -> None:
    flt = SO3OneEuroFilter(OneEuroConfig(1.0, 0.0))
    flt(np.eye(3), 0.0)
    flt.reset()
    R = so3_exp(np.array([0.0, 0.0, 2.0]))
    assert np.array_equal(flt(R, 0.1), R)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"min_cutoff_hz": 0.0, "beta": 1.0},
        {"min_cutoff_hz": 1.0, "beta": -1.0},
        {"min_cutoff_hz": 1.0, "beta": 1.0, "d_cutoff_hz": float("inf")},
    ],
)
def test_filter_config_is_validated(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        OneEuroConfig(**kwargs)
