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
relative rotation R_A R_B^T forms the product (27 multiplications, as many as its trace and
skew part alone would take), then works on its 9 entries.

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


# --- compiled: one state ---------------------------------------------------------------
#
# A function of one state takes the batch arrays and the state's row in them: it reads row
# `a` of its inputs, (rows, 3), (rows, 3, 3), (rows, F), (rows, 6 + F), and writes row `m`
# of its outputs. Rows are indexed, never sliced (`jit` says why).


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
def rotate_into(w0: float, w1: float, w2: float, R: Array, a: int, out: Array, m: int) -> None:
    """out[m] (3, 3) = exp(w) R[a]; out[m] must not be R[a]."""
    E = exp_of(w0, w1, w2)
    for i in range(3):
        for j in range(3):
            out[m, i, j] = (
                E[3 * i] * R[a, 0, j] + E[3 * i + 1] * R[a, 1, j] + E[3 * i + 2] * R[a, 2, j]
            )


@kernel
def log_relative_of(Ra: Array, a: int, Rb: Array, b: int) -> tuple[float, float, float]:
    """log(Ra[a] Rb[b]^T) (module docstring), as its 3 components."""
    return log_of(product_of(Ra, a, Rb, b))


@kernel
def product_of(Ra: Array, a: int, Rb: Array, b: int) -> tuple[float, ...]:
    """Ra[a] Rb[b]^T as its 9 entries, row by row."""
    return (
        _dot3(Ra, a, 0, Rb, b, 0), _dot3(Ra, a, 0, Rb, b, 1), _dot3(Ra, a, 0, Rb, b, 2),
        _dot3(Ra, a, 1, Rb, b, 0), _dot3(Ra, a, 1, Rb, b, 1), _dot3(Ra, a, 1, Rb, b, 2),
        _dot3(Ra, a, 2, Rb, b, 0), _dot3(Ra, a, 2, Rb, b, 1), _dot3(Ra, a, 2, Rb, b, 2),
    )  # fmt: skip


@kernel
def _dot3(A: Array, a: int, i: int, B: Array, b: int, j: int) -> float:
    """(A[a] B[b]^T)_ij: row i of A[a] dotted with row j of B[b]."""
    return A[a, i, 0] * B[b, j, 0] + A[a, i, 1] * B[b, j, 1] + A[a, i, 2] * B[b, j, 2]


@kernel
def log_of(R: tuple[float, ...]) -> tuple[float, float, float]:
    """log(R) (module docstring) of a rotation given as its 9 entries, row by row.

    theta = atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2) keeps full precision at 0 and at pi
    alike (an arccos of the trace alone loses half the digits near both).
    """
    s0, s1, s2 = R[7] - R[5], R[2] - R[6], R[3] - R[1]
    cos_t = min(max((R[0] + R[4] + R[8] - 1.0) * 0.5, -1.0), 1.0)
    sin_t = 0.5 * math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    theta = math.atan2(sin_t, cos_t)
    if theta <= math.pi - _NEAR_PI_RAD:
        # theta / sin(theta), with its series 1 + theta^2 / 6 below 1e-4 rad.
        if theta < _SMALL_RAD:
            half = 0.5 * (1.0 + theta * theta / 6.0)
        else:
            half = 0.5 * theta / max(sin_t, 1e-300)
        return half * s0, half * s1, half * s2
    # Near pi: the axis from the symmetric part (module docstring): the column of its
    # largest diagonal entry, signed to agree with vee(R - R^T).
    best, k = -math.inf, 0
    for i in range(3):
        d = (R[4 * i] - cos_t) / (1.0 - cos_t)
        if d > best:
            best, k = d, i
    scale = 1.0 / (1.0 - cos_t) / math.sqrt(max(best, 1e-300))
    a0 = (0.5 * (R[k] + R[3 * k]) - (cos_t if k == 0 else 0.0)) * scale
    a1 = (0.5 * (R[3 + k] + R[3 * k + 1]) - (cos_t if k == 1 else 0.0)) * scale
    a2 = (0.5 * (R[6 + k] + R[3 * k + 2]) - (cos_t if k == 2 else 0.0)) * scale
    if a0 * s0 + a1 * s1 + a2 * s2 < 0.0:
        theta = -theta
    return theta * a0, theta * a1, theta * a2


@kernel
def diff_into(
    pa: Array, Ra: Array, ga: Array, a: int,
    pb: Array, Rb: Array, gb: Array, b: int,
    out: Array, m: int,
) -> None:  # fmt: skip
    """out[m] (6 + F,) = diff(A, B) = [p_A - p_B, log(R_A R_B^T), g_A - g_B] of the states in
    row a of A's arrays and row b of B's."""
    for i in range(3):
        out[m, i] = pa[a, i] - pb[b, i]
    for f in range(ga.shape[1]):
        out[m, 6 + f] = ga[a, f] - gb[b, f]
    out[m, 3], out[m, 4], out[m, 5] = log_relative_of(Ra, a, Rb, b)


@kernel
def integrate_into(
    p: Array, R: Array, g: Array, a: int, U: Array, u: int, dt: float,
    out_p: Array, out_R: Array, out_g: Array, m: int,
) -> None:  # fmt: skip
    """Eq (2) for one state, row a, by U[u]: p + v dt, exp(w dt) R, clip(g + gdot dt, 0, 1)."""
    for i in range(3):
        out_p[m, i] = p[a, i] + U[u, i] * dt
    rotate_into(U[u, 3] * dt, U[u, 4] * dt, U[u, 5] * dt, R, a, out_R, m)
    for f in range(g.shape[1]):
        out_g[m, f] = min(max(g[a, f] + U[u, 6 + f] * dt, 0.0), 1.0)


@kernel
def group_norm(x: Array, a: int, start: int, stop: int) -> float:
    """Euclidean norm of x[a, start:stop]."""
    s = 0.0
    for i in range(start, stop):
        s += x[a, i] * x[a, i]
    return math.sqrt(s)


@kernel
def saturate_into(U: Array, a: int, v_max: Array, out: Array, m: int) -> None:
    """out[m] (6 + F,) = U[a] with translation and rotation scaled to |.| <= v_max[0],
    v_max[3] and each finger clipped to +-v_max[6 + f] (out[m] may be U[a])."""
    _scale_into(U, a, 0, v_max[0], out, m)
    _scale_into(U, a, 3, v_max[3], out, m)
    for i in range(6, U.shape[1]):
        out[m, i] = min(max(U[a, i], -v_max[i]), v_max[i])


@kernel
def _scale_into(U: Array, a: int, start: int, limit: float, out: Array, m: int) -> None:
    """out[m, start:start + 3] = U[a, start:start + 3] scaled to a norm of at most `limit`.

    The norm is written out rather than taken from `group_norm`: the row is read into floats
    before the branch of min/max, so out[m] may be U[a] (`jit` says why reads come first)."""
    u0, u1, u2 = U[a, start], U[a, start + 1], U[a, start + 2]
    scale = min(1.0, limit / max(math.sqrt(u0 * u0 + u1 * u1 + u2 * u2), 1e-300))
    out[m, start], out[m, start + 1], out[m, start + 2] = u0 * scale, u1 * scale, u2 * scale


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
            Ra, row(Ra.shape[0], m), Rb, row(Rb.shape[0], m)
        )
    return out


@kernel
def _diff_batch(pa: Array, Ra: Array, ga: Array, pb: Array, Rb: Array, gb: Array, M: int) -> Array:
    out = np.empty((M, 6 + ga.shape[1]))
    for m in range(M):
        diff_into(pa, Ra, ga, row(pa.shape[0], m), pb, Rb, gb, row(pb.shape[0], m), out, m)
    return out


@kernel
def _integrate_batch(
    p: Array, R: Array, g: Array, U: Array, dt: float, M: int
) -> tuple[Array, Array, Array]:
    out_p, out_R, out_g = np.empty((M, 3)), np.empty((M, 3, 3)), np.empty((M, g.shape[1]))
    for m in range(M):
        integrate_into(
            p, R, g, row(p.shape[0], m), U, row(U.shape[0], m), dt, out_p, out_R, out_g, m
        )
    return out_p, out_R, out_g


@kernel
def _saturate_batch(U: Array, v_max: Array) -> Array:
    out = np.empty_like(U)
    for m in range(U.shape[0]):
        saturate_into(U, m, v_max, out, m)
    return out


# --- the usual layout ---------------------------------------------------------------------


def batch_of(*shapes: tuple[int, ...]) -> tuple[int, ...]:
    """The batch shape the given ones broadcast to (checked cheaply when all are equal)."""
    first = shapes[0]
    if all(s == first for s in shapes[1:]):
        return first
    return tuple(np.broadcast_shapes(*shapes))


def state_input(X: HandState, batch: tuple[int, ...]) -> tuple[Array, Array, Array]:
    """A state's three arrays for a compiled function of a batch `batch` (`jit.as_input`),
    all with M rows, or all with one if the state is shared by every row: one row index
    reads the state."""
    if math.prod(X.batch) == 1:
        return as_input(X.position, (), 1), as_input(X.rotation, (), 2), as_input(X.openness, (), 1)
    return (
        as_input(X.position, batch, 1, shared=False),
        as_input(X.rotation, batch, 2, shared=False),
        as_input(X.openness, batch, 1, shared=False),
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
    """so3_log(Ra Rb^T), (..., 3, 3) each -> (..., 3)."""
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
