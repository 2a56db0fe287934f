"""Pose differences, velocity saturation and integration on SE(3) x [0, 1]^F (DESIGN.md §2).

A hand state X is a palm pose in the robot base frame plus finger openness. The difference
of two states is a (6 + F)-vector

    diff(A, B) = [p_A - p_B,  log(R_A R_B^T),  g_A - g_B]

where log is the SO(3) logarithm (a rotation vector in the base frame). Euler angles are
never differenced or blended. Integration over dt (eq 2) is the inverse:

    p' = p + v dt,   R' = exp(w dt) R,   g' = clip(g + gdot dt, 0, 1).

Saturation keeps directions: translation and rotation are scaled by their norms (a straight
line stays straight), each finger is clipped alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

TRANS = slice(0, 3)
ROT = slice(3, 6)
FING = slice(6, None)
AXIS_NAMES = ("x", "y", "z", "roll", "pitch", "yaw")


def dim_names(finger_names: tuple[str, ...] | int) -> tuple[str, ...]:
    """Names of the 6 + F arbitration dimensions (fingers by name, or f0..f{F-1})."""
    if isinstance(finger_names, int):
        finger_names = tuple(f"f{i}" for i in range(finger_names))
    return AXIS_NAMES + tuple(finger_names)


@dataclass(frozen=True)
class HandState:
    """Palm pose and finger openness in the robot base frame; any leading batch shape.

    Attributes:
        position: (..., 3) palm position [m].
        rotation: (..., 3, 3) rotation matrix R_base_palm.
        openness: (..., F) finger openness in [0, 1], 1 = fully open.
    """

    position: Array
    rotation: Array
    openness: Array

    @property
    def n_fingers(self) -> int:
        return int(self.openness.shape[-1])

    @classmethod
    def from_rotvec(
        cls,
        position: Array | list[float],
        rotvec: Array | list[float],
        openness: Array | list[float],
    ) -> HandState:
        """Build a state from a rotation vector [rad] instead of a matrix."""
        return cls(
            np.asarray(position, dtype=np.float64),
            so3_exp(np.asarray(rotvec, dtype=np.float64)),
            np.asarray(openness, dtype=np.float64),
        )

    def rotvec(self) -> Array:
        """Orientation as a rotation vector [rad], (..., 3)."""
        return so3_log(self.rotation)

    def is_finite(self) -> bool:
        return bool(
            np.isfinite(self.position).all()
            and np.isfinite(self.rotation).all()
            and np.isfinite(self.openness).all()
        )


def hat(w: Array) -> Array:
    """Skew-symmetric matrix of w, (..., 3) -> (..., 3, 3)."""
    K = np.zeros((*w.shape[:-1], 3, 3))
    K[..., 0, 1] = -w[..., 2]
    K[..., 0, 2] = w[..., 1]
    K[..., 1, 0] = w[..., 2]
    K[..., 1, 2] = -w[..., 0]
    K[..., 2, 0] = -w[..., 1]
    K[..., 2, 1] = w[..., 0]
    return K


def so3_exp(w: Array) -> Array:
    """Rotation matrix of a rotation vector (Rodrigues), (..., 3) -> (..., 3, 3)."""
    w = np.asarray(w, dtype=np.float64)
    theta2 = (w * w).sum(-1)
    theta = np.sqrt(theta2)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1 - cos t)/t^2, with their Taylor series near 0.
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    K = hat(w)
    return _EYE + a[..., None, None] * K + b[..., None, None] * (K @ K)


_EYE = np.eye(3)
_VEE_I = np.array([2, 0, 1])
_VEE_J = np.array([1, 2, 0])


def so3_log(R: Array) -> Array:
    """Rotation vector of a rotation matrix, angle in [0, pi], (..., 3, 3) -> (..., 3)."""
    R = np.asarray(R, dtype=np.float64)
    if R.ndim != 3:
        return so3_log(R.reshape(-1, 3, 3)).reshape((*R.shape[:-2], 3))
    cos_t = np.minimum(np.maximum((R.trace(axis1=-2, axis2=-1) - 1.0) * 0.5, -1.0), 1.0)
    theta = np.arccos(cos_t)
    # v = sin(theta) * axis, from the skew-symmetric part of R.
    v = 0.5 * (R[..., _VEE_I, _VEE_J] - R[..., _VEE_J, _VEE_I])
    small = theta < 1e-4
    near_pi = theta > np.pi - 1e-3
    regular = ~(small | near_pi)
    scale = np.where(
        small, 1.0 + theta * theta / 6.0, theta / np.where(regular, np.sin(theta), 1.0)
    )
    out = scale[..., None] * v
    idx = np.flatnonzero(near_pi)
    if idx.size:
        # Near pi, sin(theta) loses the axis; use the symmetric part instead:
        # a a^T = ((R + R^T) / 2 - cos(theta) I) / (1 - cos(theta)), exact for any theta.
        # Take the column of its largest diagonal entry, signed to agree with v.
        Rn, cn = R[idx], cos_t[idx][:, None, None]
        Bm = (0.5 * (Rn + np.swapaxes(Rn, -1, -2)) - cn * _EYE) / (1.0 - cn)
        diag = np.diagonal(Bm, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        m = np.arange(k.size)
        col = Bm[m, :, k]
        axis = col / np.sqrt(np.maximum(diag[m, k], 1e-300))[:, None]
        sign = np.where((axis * v[idx]).sum(-1) < 0.0, -1.0, 1.0)
        out[idx] = (theta[idx] * sign)[:, None] * axis
    return out


def diff(A: HandState, B: HandState) -> Array:
    """Difference A - B of two hand states as a (..., 6 + F) vector (see module docstring)."""
    rot = so3_log(A.rotation @ np.swapaxes(B.rotation, -1, -2))
    return np.concatenate([A.position - B.position, rot, A.openness - B.openness], -1)


def integrate(X: HandState, U: Array, dt: float) -> HandState:
    """Eq (2): apply the velocity U (..., 6 + F) to X for dt [s]."""
    return HandState(
        X.position + U[..., TRANS] * dt,
        so3_exp(U[..., ROT] * dt) @ X.rotation,
        np.minimum(np.maximum(X.openness + U[..., FING] * dt, 0.0), 1.0),
    )


def group_norms(x: Array) -> Array:
    """Euclidean norms of the translation, rotation and finger groups, (..., D) -> (..., 3).

    With no fingers (D = 6) the last column is 0.
    """
    sq = x * x
    if x.shape[-1] > 6:
        return np.sqrt(np.add.reduceat(sq, _GROUP_STARTS, axis=-1))
    out = np.zeros((*x.shape[:-1], 3))
    out[..., :2] = np.sqrt(np.add.reduceat(sq, _GROUP_STARTS[:2], axis=-1))
    return out


_GROUP_STARTS = np.array([0, 3, 6])


def saturate(U: Array, v_max: Array) -> Array:
    """Scale translation and rotation by their norms and clip fingers to the limits.

    Args:
        U: (..., 6 + F) velocities.
        v_max: (6 + F,) limits; v_max[0] bounds |v| [m/s], v_max[3] bounds |w| [rad/s],
            v_max[6:] bound each finger [1/s].
    """
    n = group_norms(U)[..., :2]
    fac = np.minimum(1.0, v_max[0:4:3] / np.maximum(n, 1e-300))
    out = np.array(U, dtype=np.float64, copy=True)
    out[..., TRANS] *= fac[..., 0:1]
    out[..., ROT] *= fac[..., 1:2]
    out[..., FING] = np.minimum(np.maximum(out[..., FING], -v_max[FING]), v_max[FING])
    return out
