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
(..., 6 + F). Each is a thin wrapper over a "rows" form (`*_rows`), components first with
the batch flattened last: (3, M), (3, 3, M), (6 + F, M). There every operation is one pass
over a contiguous row of M values, which is what makes a batch of thousands fast in numpy;
the arbitration kernel works in rows throughout (`arbiters.py`). The maths is written once,
in the rows form.

Quaternions are unit (w, x, y, z), w >= 0 (viser's order); other orders are converted where
they cross a library boundary (PyBullet's xyzw in `robot/`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

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


# --- rows layout ------------------------------------------------------------------------


@dataclass(frozen=True)
class StateRows:
    """A batch of M hand states in rows form: position (3, M), rotation (3, 3, M), openness
    (F, M), each row contiguous (module docstring)."""

    p: Array
    R: Array
    g: Array

    @classmethod
    def of(cls, *states: HandState, batch: tuple[int, ...]) -> StateRows:
        """The states broadcast to `batch`, in rows form, side by side when there are several
        (M = len(states) * prod(batch); the k-th state's rows are columns k M0 .. (k+1) M0)."""
        M0 = math.prod(batch)
        F = states[0].openness.shape[-1]
        n = len(states)
        p, R, g = np.empty((3, n * M0)), np.empty((9, n * M0)), np.empty((F, n * M0))

        def put(out: Array, x: Array, tail: tuple[int, ...], cols: slice) -> None:
            if x.shape[: x.ndim - len(tail)] != batch:
                x = np.broadcast_to(x, (*batch, *tail))
            out[:, cols] = x.reshape(M0, out.shape[0]).T

        for k, X in enumerate(states):
            cols = slice(k * M0, (k + 1) * M0)
            put(p, X.position, (3,), cols)
            put(R, X.rotation, (3, 3), cols)
            put(g, X.openness, (F,), cols)
        return cls(p, R.reshape(3, 3, n * M0), g)

    def part(self, k: int, M0: int) -> StateRows:
        """The k-th of several states laid side by side by `of` (views)."""
        cols = slice(k * M0, (k + 1) * M0)
        return StateRows(self.p[:, cols], self.R[..., cols], self.g[:, cols])

    def state(self, batch: tuple[int, ...]) -> HandState:
        """Back to the usual layout with batch shape `batch`."""
        return HandState(
            from_rows(self.p, batch), from_rows(self.R, batch), from_rows(self.g, batch)
        )


def to_rows(x: Array, M: int, vector_axes: int) -> Array:
    """(..., k) or (..., 3, 3) -> (k, M) or (3, 3, M), contiguous (a copy, or a view for a
    single state)."""
    tail = x.shape[x.ndim - vector_axes :]
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == vector_axes:  # one state: already components first
        return x.reshape(*tail, 1)
    flat = x.reshape(M, math.prod(tail))
    return np.ascontiguousarray(flat.T).reshape(*tail, M)


def from_rows(x: Array, batch: tuple[int, ...]) -> Array:
    """(k, M) or (3, 3, M) -> (..., k) or (..., 3, 3) with batch shape `batch` (a view)."""
    tail = x.shape[:-1]
    if not batch:
        return x.reshape(tail)
    return x.reshape(math.prod(tail), x.shape[-1]).T.reshape(*batch, *tail)


def exp_rows(w: Array) -> Array:
    """so3_exp in rows form: w (3, M) -> (3, 3, M)."""
    t2 = _sum3(w * w)
    t = np.sqrt(t2)
    small = t < _SMALL_RAD
    safe = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    R = (b * w)[:, None] * w[None, :]  # b w w^T
    R.reshape(9, -1)[::4] += 1.0 - b * t2  # the diagonal
    aw = a * w  # + a hat(w)
    R[0, 1] -= aw[2]
    R[1, 0] += aw[2]
    R[0, 2] += aw[1]
    R[2, 0] -= aw[1]
    R[1, 2] -= aw[0]
    R[2, 1] += aw[0]
    return R


def matmul_rows(A: Array, B: Array) -> Array:
    """A B for rows-form matrices (3, 3, M)."""
    out = np.empty(np.broadcast_shapes(A.shape, B.shape))
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return out


def log_relative_rows(Ra: Array, Rb: Array) -> Array:
    """so3_log(Ra Rb^T) in rows form: (3, 3, M) each -> (3, M) (module docstring)."""
    # trace(Ra Rb^T) = sum_ij a_ij b_ij; 2 vee(skew) = (m21 - m12, m02 - m20, m10 - m01) with
    # m_ij = sum_k a_ik b_jk. Sums written out in a fixed order, so that a state gives the
    # same bits alone and in a batch.
    prod = Ra * Rb
    trace = _sum3(_sum3(prod[0]), _sum3(prod[1]), _sum3(prod[2]))
    skew2 = np.empty((3, trace.shape[-1]))
    for i, j, k in ((0, 2, 1), (1, 0, 2), (2, 1, 0)):
        skew2[i] = _sum3(Ra[j] * Rb[k]) - _sum3(Ra[k] * Rb[j])

    def products(idx: NDArray[np.intp]) -> Array:
        return np.einsum("ikm,jkm->mij", Ra[..., idx], Rb[..., idx])

    return _log(trace, skew2, products)


def _sum3(a: Array, b: Array | None = None, c: Array | None = None) -> Array:
    """a[0] + a[1] + a[2] of a (3, M) array, or a + b + c of three (M,) arrays."""
    if b is None or c is None:
        return np.asarray(a[0] + a[1] + a[2])
    return np.asarray(a + b + c)


def _log(trace: Array, skew2: Array, products: Callable[[NDArray[np.intp]], Array]) -> Array:
    """The logarithm from trace(R) (M,) and 2 vee(skew R) (3, M) -> (3, M) (module docstring).

    theta = atan2(|vee(skew R)|, (trace - 1) / 2): full precision at 0 and at pi alike (an
    arccos of the trace alone loses half the digits near both). `products(indices)` gives
    the matrices R (n, 3, 3) of the pairs near pi.
    """
    cos_t = np.clip((trace - 1.0) * 0.5, -1.0, 1.0)
    sin_t = 0.5 * np.sqrt(_sum3(skew2 * skew2))
    theta = np.arctan2(sin_t, cos_t)
    small = theta < _SMALL_RAD
    near_pi = theta > np.pi - _NEAR_PI_RAD
    # theta / sin(theta), with its series 1 + theta^2 / 6 below 1e-4 rad (and 1 near pi,
    # where the axis is recomputed below).
    ratio = np.where(small | near_pi, 1.0 + theta * theta / 6.0, theta / np.maximum(sin_t, 1e-300))
    half_scale = 0.5 * ratio
    out = half_scale * skew2
    idx = np.flatnonzero(near_pi)
    if idx.size:
        Rn = products(idx)
        cn = cos_t[idx][:, None, None]
        sym = (0.5 * (Rn + np.swapaxes(Rn, -1, -2)) - cn * _EYE) / (1.0 - cn)
        diag = np.diagonal(sym, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        m = np.arange(k.size)
        axis = sym[m, :, k] / np.sqrt(np.maximum(diag[m, k], 1e-300))[:, None]
        sign = np.where((axis * skew2[:, idx].T).sum(-1) < 0.0, -1.0, 1.0)
        out[:, idx] = ((theta[idx] * sign)[:, None] * axis).T
    return out


_EYE = np.eye(3)


def diff_rows(A: StateRows, B: StateRows) -> Array:
    """diff in rows form: (6 + F, M)."""
    F = A.g.shape[0]
    M = max(A.p.shape[-1], B.p.shape[-1])
    out = np.empty((6 + F, M))
    np.subtract(A.p, B.p, out=out[TRANS])
    out[ROT] = log_relative_rows(A.R, B.R)
    np.subtract(A.g, B.g, out=out[FING])
    return out


def integrate_rows(X: StateRows, U: Array, dt: float) -> StateRows:
    """integrate in rows form: U (6 + F, M)."""
    return StateRows(
        X.p + U[TRANS] * dt,
        matmul_rows(exp_rows(U[ROT] * dt), X.R),
        np.clip(X.g + U[FING] * dt, 0.0, 1.0),
    )


def norms_rows(x: Array) -> Array:
    """Euclidean norm over the first axis: (k, ...) -> (...)."""
    return np.sqrt((x * x).sum(0))


def saturate_rows(U: Array, v_max: Array) -> Array:
    """saturate in rows form: U (6 + F, M), v_max (6 + F,)."""
    out = np.empty_like(U)
    for g in (TRANS, ROT):
        limit = v_max[g.start]
        np.multiply(U[g], np.minimum(1.0, limit / np.maximum(norms_rows(U[g]), 1e-300)), out=out[g])
    vf = v_max[FING, None]
    np.clip(U[FING], -vf, vf, out=out[FING])
    return out


# --- the usual layout ---------------------------------------------------------------------


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
    return from_rows(exp_rows(to_rows(w, math.prod(batch), 1)), batch)


def so3_log(R: Array) -> Array:
    """Rotation vector of a rotation matrix, angle in [0, pi], (..., 3, 3) -> (..., 3)."""
    R = np.asarray(R, dtype=np.float64)
    batch = R.shape[:-2]
    Rr = to_rows(R, math.prod(batch), 2)
    trace = Rr[0, 0] + Rr[1, 1] + Rr[2, 2]
    skew2 = np.stack([Rr[2, 1] - Rr[1, 2], Rr[0, 2] - Rr[2, 0], Rr[1, 0] - Rr[0, 1]])
    return from_rows(_log(trace, skew2, lambda idx: np.moveaxis(Rr[..., idx], -1, 0)), batch)


def log_relative(Ra: Array, Rb: Array) -> Array:
    """so3_log(Ra Rb^T), (..., 3, 3) each -> (..., 3), without forming the product."""
    batch = np.broadcast_shapes(np.shape(Ra)[:-2], np.shape(Rb)[:-2])
    M = math.prod(batch)
    a = to_rows(np.broadcast_to(Ra, (*batch, 3, 3)), M, 2)
    b = to_rows(np.broadcast_to(Rb, (*batch, 3, 3)), M, 2)
    return from_rows(log_relative_rows(a, b), batch)


def diff(A: HandState, B: HandState) -> Array:
    """Difference A - B of two hand states as a (..., 6 + F) vector (module docstring)."""
    batch = np.broadcast_shapes(A.batch, B.batch)
    return from_rows(diff_rows(StateRows.of(A, batch=batch), StateRows.of(B, batch=batch)), batch)


def integrate(X: HandState, U: Array, dt: float) -> HandState:
    """Eq (2): apply the velocity U (..., 6 + F) to X for dt [s]."""
    batch = np.broadcast_shapes(X.batch, U.shape[:-1])
    U_rows = to_rows(np.broadcast_to(U, (*batch, U.shape[-1])), math.prod(batch), 1)
    return integrate_rows(StateRows.of(X, batch=batch), U_rows, dt).state(batch)


def group_norms(x: Array) -> Array:
    """Euclidean norms of the translation, rotation and finger groups, (..., D) -> (..., 3).

    With no fingers (D = 6) the last column is 0.
    """
    rows = np.moveaxis(x, -1, 0)
    return np.stack([norms_rows(rows[g]) for g in (TRANS, ROT, FING)], -1)


def saturate(U: Array, v_max: Array) -> Array:
    """Scale translation and rotation by their norms and clip fingers to the limits.

    Args:
        U: (..., 6 + F) velocities.
        v_max: (6 + F,) limits; v_max[0] bounds |v| [m/s], v_max[3] bounds |w| [rad/s],
            v_max[6:] bound each finger [1/s].
    """
    U = np.asarray(U, dtype=np.float64)
    batch = U.shape[:-1]
    return from_rows(saturate_rows(to_rows(U, math.prod(batch), 1), v_max), batch)


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
