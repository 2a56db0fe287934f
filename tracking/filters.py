"""One Euro filters (Casiez, Roussel and Vogel, CHI 2012) on R^n and on SO(3).

For a sample x_k at time t_k (dt = t_k - t_{k-1} > 0), with the smoothing factor of a
first-order low-pass of cutoff f [Hz]

    a(f) = 1 / (1 + 1 / (2 pi f dt)),

the filter estimates the derivative, low-passes it at `d_cutoff_hz`, and low-passes the
signal at a cutoff that rises with the speed:

    dx_k    = (x_k - xhat_{k-1}) / dt
    dxhat_k = dxhat_{k-1} + a(d_cutoff) (dx_k - dxhat_{k-1})
    f_k     = min_cutoff + beta |dxhat_k|
    xhat_k  = xhat_{k-1} + a(f_k) (x_k - xhat_{k-1}).

Slow motion (jitter) sees a low cutoff, fast motion a high one (little lag). On R^n the
speed |dxhat| is either the vector norm (one cutoff for the whole vector: a 3-D position
keeps its direction of motion) or per component (independent channels such as fingers).

On SO(3) the same recursion runs on rotation increments, never on Euler angles:

    w_k    = log(R_k Rhat_{k-1}^T) / dt        (angular velocity in the base frame, rad/s)
    Rhat_k = exp(a(f_k) log(R_k Rhat_{k-1}^T)) Rhat_{k-1},   f_k = min_cutoff + beta |what_k|,

i.e. the geodesic from the previous estimate towards the new sample, a fraction a(f_k) of
the way (slerp). A non-positive dt (a repeated or out-of-order timestamp) keeps the
previous estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dsteleop.arbitration.se3 import so3_exp, so3_log
from dsteleop.errors import ConfigError
from dsteleop.tracking.types import Array


@dataclass(frozen=True)
class OneEuroConfig:
    """Parameters of one One Euro filter.

    Attributes:
        min_cutoff_hz: cutoff at rest [Hz]; lower = less jitter, more lag when slow.
        beta: cutoff increase per unit of speed [Hz per (unit/s)]: the units of the
            signal (m, rad, openness) set its scale.
        d_cutoff_hz: cutoff of the derivative estimate [Hz].
    """

    min_cutoff_hz: float
    beta: float
    d_cutoff_hz: float = 1.0

    def __post_init__(self) -> None:
        for name in ("min_cutoff_hz", "d_cutoff_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ConfigError(f"beta must be finite and >= 0, got {self.beta!r}")


@dataclass(frozen=True)
class HandFilterConfig:
    """One Euro parameters of the three tracked quantities.

    Defaults (checked on the `tracking` bench: a synthetic still hand with MediaPipe-like
    noise loses ~80 % of its frame-to-frame jitter, a 0.5 m/s move lags ~11 ms):
        position: 1.0 Hz at rest, +20 Hz per m/s: at 0.25 m/s the cutoff is 6 Hz.
        orientation: 1.0 Hz at rest, +2 Hz per rad/s: at 2 rad/s the cutoff is 5 Hz.
        openness: 1.5 Hz at rest, +2 Hz per 1/s, per finger.
    """

    position: OneEuroConfig = OneEuroConfig(min_cutoff_hz=1.0, beta=20.0)
    orientation: OneEuroConfig = OneEuroConfig(min_cutoff_hz=1.0, beta=2.0)
    openness: OneEuroConfig = OneEuroConfig(min_cutoff_hz=1.5, beta=2.0)
    enabled: bool = True


def smoothing_factor(cutoff_hz: float | Array, dt_s: float) -> float | Array:
    """a(f) = 1 / (1 + 1 / (2 pi f dt)) of a first-order low-pass (module docstring)."""
    return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff_hz * dt_s))


class OneEuroFilter:
    """One Euro filter on a vector signal (module docstring).

    Args:
        config: filter parameters.
        per_component: one cutoff per component (True) or one from the vector norm (False).
    """

    def __init__(self, config: OneEuroConfig, per_component: bool = False) -> None:
        self.config = config
        self.per_component = per_component
        self._x: Array | None = None
        self._dx: Array | None = None
        self._t: float = 0.0

    def reset(self) -> None:
        """Forget the state: the next sample passes through unchanged."""
        self._x = None
        self._dx = None

    @property
    def value(self) -> Array | None:
        """The current estimate, or None before the first sample."""
        return self._x

    def __call__(self, x: Array, t_s: float) -> Array:
        """Filter one sample taken at t_s [s] and return the estimate."""
        x = np.asarray(x, dtype=np.float64)
        if self._x is None or self._dx is None:
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), t_s
            return self._x.copy()
        dt = t_s - self._t
        if dt <= 0.0:
            return self._x.copy()
        cfg = self.config
        dx = (x - self._x) / dt
        self._dx = self._dx + smoothing_factor(cfg.d_cutoff_hz, dt) * (dx - self._dx)
        speed = np.abs(self._dx) if self.per_component else float(np.linalg.norm(self._dx))
        a = smoothing_factor(cfg.min_cutoff_hz + cfg.beta * speed, dt)
        self._x = self._x + a * (x - self._x)
        self._t = t_s
        return self._x.copy()


class SO3OneEuroFilter:
    """One Euro filter on rotation matrices, by geodesic steps (module docstring)."""

    def __init__(self, config: OneEuroConfig) -> None:
        self.config = config
        self._R: Array | None = None
        self._w = np.zeros(3)
        self._t = 0.0

    def reset(self) -> None:
        """Forget the state: the next sample passes through unchanged."""
        self._R = None
        self._w = np.zeros(3)

    @property
    def value(self) -> Array | None:
        """The current estimate, or None before the first sample."""
        return self._R

    def __call__(self, R: Array, t_s: float) -> Array:
        """Filter one rotation matrix taken at t_s [s] and return the estimate."""
        R = np.asarray(R, dtype=np.float64)
        if self._R is None:
            self._R, self._w, self._t = R.copy(), np.zeros(3), t_s
            return self._R.copy()
        dt = t_s - self._t
        if dt <= 0.0:
            return self._R.copy()
        cfg = self.config
        delta = so3_log(R @ self._R.T)
        self._w = self._w + smoothing_factor(cfg.d_cutoff_hz, dt) * (delta / dt - self._w)
        speed = float(np.linalg.norm(self._w))
        a = float(smoothing_factor(cfg.min_cutoff_hz + cfg.beta * speed, dt))
        R_new = so3_exp(a * delta) @ self._R
        # Re-orthonormalise: rounding errors of repeated products must not accumulate.
        u, _, vt = np.linalg.svd(R_new)
        self._R = u @ vt
        self._t = t_s
        return self._R.copy()
