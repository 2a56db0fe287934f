"""Poses, rotations and their differences: the project's only SO(3) and quaternion maths.

A hand state X is a palm pose in the robot base frame plus finger openness. The difference
of two states is a (6 + F)-vector

    diff(A, B) = [p_A - p_B,  log(R_A R_B^T),  g_A - g_B]

where log is the SO(3) logarithm (a rotation vector in the base frame, angle in [0, pi]).
Euler angles are never differenced or blended. Integration over dt (eq 2) is its inverse:

    p' = p + v dt,   R' = exp(w dt) R,   g' = clip(g + gdot dt, 0, 1).

Saturation keeps directions: translation and rotation are scaled by their norms (a straight
line stays straight), each finger is clipped alone.

Exp and log (Rodrigues):

    exp(w) = (1 - b t^2) I + a hat(w) + b w w^T,   t = |w|, a = sin(t)/t, b = (1 - cos t)/t^2
    log(R) = theta / (2 sin theta) * vee(R - R^T),
             theta = atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2)

with their series below 1e-4 rad. Within 1e-3 rad of pi, sin(theta) loses the axis; it then
comes from the symmetric part, a a^T = ((R + R^T)/2 - cos(theta) I) / (1 - cos(theta)): the
column of its largest diagonal entry, signed to agree with vee(R - R^T). The logarithm of a
relative rotation R_A R_B^T needs only the trace and the skew part of the product, sums of
elementwise products of the two matrices; only the rare pairs near pi build the product.

Layout. The public functions take the usual layout, vectors last: (..., 3), (..., 3, 3),
(..., 6 + F), with any batch shape (broadcast). The maths is written once, for one state,
in compiled functions (`*_into`, `jit.kernel`) that the arbitration kernel (`arbiters.py`)
calls per row; each public function is a loop of them over its flattened batch.

Quaternions are unit (w, x, y, z), w >= 0 (viser's order); other orders are converted where
they cross a library boundary (PyBullet's xyzw in `robot/`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.jit import as_input, kernel

Array = NDArray[np.float64]

TRANS = slice(0, 3)
ROT = slice(3, 6)
FING = slice(6, None)
AXIS_NAMES = ("x", "y", "z", "roll", "pitch", "yaw")

_SMALL_RAD = 1e-4  # below: the series of theta / sin(theta), sin(t)/t, (1 - cos t)/t^2
_NEAR_PI_RAD = 1e-3  # within this of pi: the axis from the symmetric part


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

    @property
    def batch(self) -> tuple[int, ...]:
        """The batch shape (...), broadcast over the three arrays."""
        b = self.position.shape[:-1]
        if b == self.rotation.shape[:-2] == self.openness.shape[:-1]:
            return b
        return tuple(np.broadcast_shapes(b, self.rotation.shape[:-2], self.openness.shape[:-1]))

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

    def take(self, index: NDArray[np.bool_] | NDArray[np.intp] | int) -> HandState:
        """The batch rows `index` of the first axis."""
        return HandState(self.position[index], self.rotation[index], self.openness[index])


def stack(states: Sequence[HandState], axis: int = 0) -> HandState:
    """States stacked along a new batch axis (`axis` counts from the front)."""
    return HandState(
        np.stack([s.position for s in states], axis),
        np.stack([s.rotation for s in states], axis),
        np.stack([s.openness for s in states], axis),
    )


# --- compiled: one state --------------------------------------------------------------


@kernel
def row(n: int, m: int) -> int:
    """The row of an input with n rows for batch row m: its own, or its only one (shared)."""
    return m if n > 1 else 0


@kernel
def exp_of(w0: float, w1: float, w2: float) -> tuple[float, ...]:
    """exp(w) (module docstring) as its 9 entries, row by row."""
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    t = math.sqrt(t2)
    if t < _SMALL_RAD:
        a = 1.0 - t2 / 6.0
        b = 0.5 - t2 / 24.0
    else:
        a = math.sin(t) / t
        b = (1.0 - math.cos(t)) / (t * t)
    c = 1.0 - b * t2
    return (
        b * w0 * w0 + c, b * w0 * w1 - a * w2, b * w0 * w2 + a * w1,
        b * w1 * w0 + a * w2, b * w1 * w1 + c, b * w1 * w2 - a * w0,
        b * w2 * w0 - a * w1, b * w2 * w1 + a * w0, b * w2 * w2 + c,
    )  # fmt: skip


@kernel
def rotate_into(w0: float, w1: float, w2: float, R: Array, out: Array) -> None:
    """out (3, 3) = exp(w) R; out must not be R."""
    E = exp_of(w0, w1, w2)
    for i in range(3):
        for j in range(3):
            out[i, j] = E[3 * i] * R[0, j] + E[3 * i + 1] * R[1, j] + E[3 * i + 2] * R[2, j]


@kernel
def log_relative_of(Ra: Array, Rb: Array) -> tuple[float, float, float]:
    """log(Ra Rb^T) (module docstring), as its 3 components.

    trace(Ra Rb^T) = sum_ij a_ij b_ij and 2 vee(skew) = (m21 - m12, m02 - m20, m10 - m01)
    with m_ij = sum_k a_ik b_jk; theta = atan2(|vee(skew)|, (trace - 1) / 2) keeps full
    precision at 0 and at pi alike (an arccos of the trace alone loses half the digits near
    both).
    """
    tr = 0.0
    for i in range(3):
        tr += Ra[i, 0] * Rb[i, 0] + Ra[i, 1] * Rb[i, 1] + Ra[i, 2] * Rb[i, 2]
    s0 = _dot3(Ra, 2, Rb, 1) - _dot3(Ra, 1, Rb, 2)
    s1 = _dot3(Ra, 0, Rb, 2) - _dot3(Ra, 2, Rb, 0)
    s2 = _dot3(Ra, 1, Rb, 0) - _dot3(Ra, 0, Rb, 1)
    cos_t = min(max((tr - 1.0) * 0.5, -1.0), 1.0)
    sin_t = 0.5 * math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    theta = math.atan2(sin_t, cos_t)
    if theta <= math.pi - _NEAR_PI_RAD:
        # theta / sin(theta), with its series 1 + theta^2 / 6 below 1e-4 rad.
        if theta < _SMALL_RAD:
            half = 0.5 * (1.0 + theta * theta / 6.0)
        else:
            half = 0.5 * theta / max(sin_t, 1e-300)
        return half * s0, half * s1, half * s2
    # Near pi: the axis from the symmetric part of R = Ra Rb^T (module docstring): the
    # column of its largest diagonal entry, signed to agree with vee(R - R^T).
    best, k = -math.inf, 0
    for i in range(3):
        d = (_dot3(Ra, i, Rb, i) - cos_t) / (1.0 - cos_t)
        if d > best:
            best, k = d, i
    scale = 1.0 / (1.0 - cos_t) / math.sqrt(max(best, 1e-300))
    a0 = (0.5 * (_dot3(Ra, 0, Rb, k) + _dot3(Ra, k, Rb, 0)) - (cos_t if k == 0 else 0.0)) * scale
    a1 = (0.5 * (_dot3(Ra, 1, Rb, k) + _dot3(Ra, k, Rb, 1)) - (cos_t if k == 1 else 0.0)) * scale
    a2 = (0.5 * (_dot3(Ra, 2, Rb, k) + _dot3(Ra, k, Rb, 2)) - (cos_t if k == 2 else 0.0)) * scale
    if a0 * s0 + a1 * s1 + a2 * s2 < 0.0:
        theta = -theta
    return theta * a0, theta * a1, theta * a2


@kernel
def _dot3(A: Array, i: int, B: Array, j: int) -> float:
    """(A B^T)_ij: row i of A dotted with row j of B."""
    return A[i, 0] * B[j, 0] + A[i, 1] * B[j, 1] + A[i, 2] * B[j, 2]


@kernel
def diff_into(pa: Array, Ra: Array, ga: Array, pb: Array, Rb: Array, gb: Array, out: Array) -> None:
    """out (6 + F,) = diff(A, B) = [p_A - p_B, log(R_A R_B^T), g_A - g_B]."""
    for i in range(3):
        out[i] = pa[i] - pb[i]
    out[3], out[4], out[5] = log_relative_of(Ra, Rb)
    for f in range(ga.shape[0]):
        out[6 + f] = ga[f] - gb[f]


@kernel
def integrate_into(
    p: Array, R: Array, g: Array, U: Array, dt: float, out_p: Array, out_R: Array, out_g: Array
) -> None:
    """Eq (2) for one state: p + v dt, exp(w dt) R, clip(g + gdot dt, 0, 1)."""
    for i in range(3):
        out_p[i] = p[i] + U[i] * dt
    rotate_into(U[3] * dt, U[4] * dt, U[5] * dt, R, out_R)
    for f in range(g.shape[0]):
        out_g[f] = min(max(g[f] + U[6 + f] * dt, 0.0), 1.0)


@kernel
def group_norm(x: Array, start: int, stop: int) -> float:
    """Euclidean norm of x[start:stop]."""
    s = 0.0
    for i in range(start, stop):
        s += x[i] * x[i]
    return math.sqrt(s)


@kernel
def saturate_into(U: Array, v_max: Array, out: Array) -> None:
    """out (6 + F,) = U with translation and rotation scaled to |.| <= v_max[0], v_max[3] and
    each finger clipped to +-v_max[6 + f] (out may be U)."""
    for start in (0, 3):
        scale = min(1.0, v_max[start] / max(group_norm(U, start, start + 3), 1e-300))
        for i in range(start, start + 3):
            out[i] = U[i] * scale
    for i in range(6, U.shape[0]):
        out[i] = min(max(U[i], -v_max[i]), v_max[i])


# --- compiled: a batch (rows of the inputs as `jit.as_input` flattens them) ---------------


@kernel
def _exp_batch(w: Array) -> Array:
    out = np.empty((w.shape[0], 3, 3))
    for m in range(w.shape[0]):
        E = exp_of(w[m, 0], w[m, 1], w[m, 2])
        for k in range(9):
            out[m, k // 3, k % 3] = E[k]
    return out


@kernel
def _log_relative_batch(Ra: Array, Rb: Array, M: int) -> Array:
    out = np.empty((M, 3))
    for m in range(M):
        out[m, 0], out[m, 1], out[m, 2] = log_relative_of(
            Ra[row(Ra.shape[0], m)], Rb[row(Rb.shape[0], m)]
        )
    return out


@kernel
def _diff_batch(pa: Array, Ra: Array, ga: Array, pb: Array, Rb: Array, gb: Array, M: int) -> Array:
    out = np.empty((M, 6 + ga.shape[1]))
    for m in range(M):
        a, b = row(pa.shape[0], m), row(pb.shape[0], m)
        ra, rb = row(Ra.shape[0], m), row(Rb.shape[0], m)
        fa, fb = row(ga.shape[0], m), row(gb.shape[0], m)
        diff_into(pa[a], Ra[ra], ga[fa], pb[b], Rb[rb], gb[fb], out[m])
    return out


@kernel
def _integrate_batch(
    p: Array, R: Array, g: Array, U: Array, dt: float, M: int
) -> tuple[Array, Array, Array]:
    out_p, out_R, out_g = np.empty((M, 3)), np.empty((M, 3, 3)), np.empty((M, g.shape[1]))
    for m in range(M):
        integrate_into(
            p[row(p.shape[0], m)], R[row(R.shape[0], m)], g[row(g.shape[0], m)],
            U[row(U.shape[0], m)], dt, out_p[m], out_R[m], out_g[m],
        )  # fmt: skip
    return out_p, out_R, out_g


@kernel
def _saturate_batch(U: Array, v_max: Array) -> Array:
    out = np.empty_like(U)
    for m in range(U.shape[0]):
        saturate_into(U[m], v_max, out[m])
    return out


# --- the usual layout ---------------------------------------------------------------------


def batch_of(*shapes: tuple[int, ...]) -> tuple[int, ...]:
    """The batch shape the given ones broadcast to (checked cheaply when all are equal)."""
    first = shapes[0]
    if all(s == first for s in shapes[1:]):
        return first
    return tuple(np.broadcast_shapes(*shapes))


def state_input(X: HandState, batch: tuple[int, ...]) -> tuple[Array, Array, Array]:
    """A state's three arrays for a compiled function of a batch `batch` (`jit.as_input`)."""
    return (
        as_input(X.position, batch, 1),
        as_input(X.rotation, batch, 2),
        as_input(X.openness, batch, 1),
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
    batch = w.shape[:-1]
    return _exp_batch(as_input(w, batch, 1)).reshape(*batch, 3, 3)


def so3_log(R: Array) -> Array:
    """Rotation vector of a rotation matrix, angle in [0, pi], (..., 3, 3) -> (..., 3)."""
    return log_relative(R, _EYE)


def log_relative(Ra: Array, Rb: Array) -> Array:
    """so3_log(Ra Rb^T), (..., 3, 3) each -> (..., 3), without forming the product."""
    batch = batch_of(np.shape(Ra)[:-2], np.shape(Rb)[:-2])
    a, b = as_input(Ra, batch, 2), as_input(Rb, batch, 2)
    return _log_relative_batch(a, b, math.prod(batch)).reshape(*batch, 3)


def diff(A: HandState, B: HandState) -> Array:
    """Difference A - B of two hand states as a (..., 6 + F) vector (module docstring)."""
    batch = batch_of(A.batch, B.batch)
    out = _diff_batch(*state_input(A, batch), *state_input(B, batch), math.prod(batch))
    return out.reshape(*batch, out.shape[-1])


def integrate(X: HandState, U: Array, dt: float) -> HandState:
    """Eq (2): apply the velocity U (..., 6 + F) to X for dt [s]."""
    U = np.asarray(U, dtype=np.float64)
    batch = batch_of(X.batch, U.shape[:-1])
    p, R, g = _integrate_batch(
        *state_input(X, batch), as_input(U, batch, 1), float(dt), math.prod(batch)
    )
    return HandState(p.reshape(*batch, 3), R.reshape(*batch, 3, 3), g.reshape(*batch, -1))


def group_norms(x: Array) -> Array:
    """Euclidean norms of the translation, rotation and finger groups, (..., D) -> (..., 3).

    With no fingers (D = 6) the last column is 0.
    """
    x = np.asarray(x, dtype=np.float64)
    return np.stack([np.sqrt((x[..., g] ** 2).sum(-1)) for g in (TRANS, ROT, FING)], -1)


def saturate(U: Array, v_max: Array) -> Array:
    """Scale translation and rotation by their norms and clip fingers to the limits.

    Args:
        U: (..., 6 + F) velocities.
        v_max: (6 + F,) limits; v_max[0] bounds |v| [m/s], v_max[3] bounds |w| [rad/s],
            v_max[6:] bound each finger [1/s].
    """
    U = np.asarray(U, dtype=np.float64)
    batch = U.shape[:-1]
    out = _saturate_batch(as_input(U, batch, 1), as_input(v_max, (), 1)[0])
    return out.reshape(U.shape)


_EYE = np.eye(3)


def quat_wxyz_from_matrix(R: Array) -> Array:
    """Unit quaternions (w, x, y, z), w >= 0, of rotation matrices, (..., 3, 3) -> (..., 4).

    Shepperd's method: the largest of 1 + trace, 1 + 2 R_ii - trace picks the stable formula.
    """
    m = np.asarray(R, dtype=np.float64)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    diag = np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    cand = np.concatenate([tr[..., None], 2.0 * diag - tr[..., None]], -1)  # 4 q_i^2 - 1
    i = np.argmax(cand, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(1.0 + np.take_along_axis(cand, i[..., None], -1)[..., 0], 1e-300))
    a = m[..., 2, 1] - m[..., 1, 2]
    b = m[..., 0, 2] - m[..., 2, 0]
    c = m[..., 1, 0] - m[..., 0, 1]
    xy = m[..., 0, 1] + m[..., 1, 0]
    xz = m[..., 0, 2] + m[..., 2, 0]
    yz = m[..., 1, 2] + m[..., 2, 1]
    q = np.stack(
        [
            np.choose(i, [0.25 * s, a / s, b / s, c / s]),
            np.choose(i, [a / s, 0.25 * s, xy / s, xz / s]),
            np.choose(i, [b / s, xy / s, 0.25 * s, yz / s]),
            np.choose(i, [c / s, xz / s, yz / s, 0.25 * s]),
        ],
        -1,
    )
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def matrix_from_quat_wxyz(q: Array) -> Array:
    """Rotation matrices of quaternions (w, x, y, z), (..., 4) -> (..., 3, 3).

    The quaternion is normalised first: one from a library computed in single precision
    (PyBullet's link states) is unit only to ~1e-7, and its matrix would be as far from a
    rotation, which the logarithm then reads differently depending on the formula.
    """
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q / np.sqrt((q * q).sum(-1, keepdims=True)), -1, 0)
    m = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        -1,
    )  # fmt: skip
    return m.reshape(*m.shape[:-1], 3, 3)
