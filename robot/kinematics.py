"""Forward kinematics, Jacobian and damped-least-squares IK of the arm, compiled (numba).

PyBullet has no stateless forward kinematics and its null-space IK leaves a few millimetres
of bias, so the arm chain (base -> 7 revolute joints -> fixed flange-to-palm joint) is read
from the URDF once and evaluated here. One IK iteration, for the palm target (p*, R*):

    e   = [p* - p(q),  w_rot * log(R* R(q)^T)]                 (6,) weighted pose error
    J   = geometric Jacobian of the palm (rotation rows scaled by w_rot)
    J#  = J^T (J J^T + lambda^2 I)^-1                          damped pseudo-inverse
    J+  = J^T (J J^T + 1e-9 I)^-1                              (near-)exact pseudo-inverse
    dq  = J# e + (I - J+ J) k_null (q_rest - q)                null-space pull to the rest pose

(the projector uses the undamped inverse so the rest-pose pull leaves no bias at the tip).
    q  <- clip(q + clip(dq, +-dq_max), q_lower, q_upper)       joint limits

iterated from the previous solution until both errors are below their tolerances or the
iteration budget is spent; the error after the last step is predicted to first order
(e - J dq) instead of paying for another forward-kinematics pass. With a warm start and a
target that moves a few millimetres per tick, one iteration per tick is a resolved-rate
controller: what one tick leaves, the next one removes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.jit import as_input, kernel
from dsteleop.arbitration.se3 import exp_of, log_relative_of
from dsteleop.errors import InputError
from dsteleop.robot.urdf import UrdfModel

Array = NDArray[np.float64]


@kernel
def _solve_spd(A: Array, b: Array) -> Array:
    """x with A x = b for a small symmetric positive-definite A (Gauss-Jordan, no pivoting).

    Written out instead of `np.linalg.solve`: LAPACK through a multi-threaded BLAS costs
    ~10 us for a 6x6 system on an idle machine and up to ~1 ms on a loaded one.
    """
    n = A.shape[0]
    M = np.empty((n, n + 1))
    M[:, :n] = A
    M[:, n] = b
    for i in range(n):
        pivot = M[i, i]
        for j in range(n + 1):
            M[i, j] /= pivot
        for r in range(n):
            if r != i:
                f = M[r, i]
                for j in range(n + 1):
                    M[r, j] -= f * M[i, j]
    return M[:, n].copy()


@kernel
def _matmul4_into(A: Array, B: Array, out: Array) -> None:
    """out (4, 4) = A B; out must not be A or B."""
    for i in range(4):
        for j in range(4):
            out[i, j] = (
                A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j] + A[i, 3] * B[3, j]
            )


@kernel
def _frames(fixed: Array, axes: Array, z_axes: bool, q: Array) -> tuple[Array, Array, Array, Array]:
    """`ArmChain.frames`: joint origins (n, 3) and axes (n, 3) in the base frame, tip p, R."""
    n = q.shape[0]
    origins, axes_b = np.empty((n, 3)), np.empty((n, 3))
    T, T_next, A, Rj = np.eye(4), np.empty((4, 4)), np.empty((4, 4)), np.zeros((4, 4))
    Rj[3, 3] = 1.0
    for k in range(n):
        if z_axes:
            c, s = math.cos(q[k]), math.sin(q[k])
            Rj[0, 0], Rj[0, 1], Rj[1, 0], Rj[1, 1], Rj[2, 2] = c, -s, s, c, 1.0
        else:
            E = exp_of(axes[k, 0] * q[k], axes[k, 1] * q[k], axes[k, 2] * q[k])
            for i in range(3):
                for j in range(3):
                    Rj[i, j] = E[3 * i + j]
        _matmul4_into(fixed[k], Rj, A)  # parent -> joint frame, then the joint's rotation
        _matmul4_into(T, A, T_next)
        T[:] = T_next
        for i in range(3):
            origins[k, i] = T[i, 3]
            if z_axes:
                axes_b[k, i] = T[i, 2]
            else:
                axes_b[k, i] = T[i, 0] * axes[k, 0] + T[i, 1] * axes[k, 1] + T[i, 2] * axes[k, 2]
    _matmul4_into(T, fixed[n], T_next)
    return origins, axes_b, T_next[:3, 3].copy(), T_next[:3, :3].copy()


@kernel
def _jacobian(fixed: Array, axes: Array, z_axes: bool, q: Array) -> tuple[Array, Array, Array]:
    """`ArmChain.jacobian`: (6, n) [linear; angular] and the tip pose."""
    origins, axes_b, p, R = _frames(fixed, axes, z_axes, q)
    n = q.shape[0]
    J = np.empty((6, n))
    for k in range(n):
        a0, a1, a2 = axes_b[k, 0], axes_b[k, 1], axes_b[k, 2]
        r0, r1, r2 = p[0] - origins[k, 0], p[1] - origins[k, 1], p[2] - origins[k, 2]
        J[0, k] = a1 * r2 - a2 * r1  # axis x (p - origin)
        J[1, k] = a2 * r0 - a0 * r2
        J[2, k] = a0 * r1 - a1 * r0
        J[3, k], J[4, k], J[5, k] = a0, a1, a2
    return J, p, R


@kernel
def _ik(
    fixed: Array, axes: Array, z_axes: bool, lower: Array, upper: Array,
    p_target: Array, R_target: Array, q0: Array, q_rest: Array,
    iterations: int, tol_m: float, tol_rad: float, damping: float, w_rot_m: float,
    k_null: float, dq_max_rad: float,
) -> tuple[Array, float, float, int]:  # fmt: skip
    """`ArmChain.ik` (module docstring): q, the remaining errors [m], [rad], iterations."""
    n = q0.shape[0]
    q = np.minimum(np.maximum(q0, lower), upper)
    lam2 = damping * damping
    J, p, R = _jacobian(fixed, axes, z_axes, q)
    e_p = p_target - p
    e_r = np.empty(3)
    Rt = R_target.reshape((1, 3, 3))  # se3's functions of one state read row 0 of a batch
    e_r[0], e_r[1], e_r[2] = log_relative_of(Rt, 0, R.reshape((1, 3, 3)), 0)
    e, Jw, JJt, A = np.empty(6), np.empty((6, n)), np.empty((6, 6)), np.empty((6, 6))
    used = 0
    while True:
        converged = _dot(e_p, e_p) < tol_m * tol_m and _dot(e_r, e_r) < tol_rad * tol_rad
        if converged or used == iterations:
            break
        used += 1
        Jw[:] = J
        Jw[3:] *= w_rot_m
        e[:3] = e_p
        e[3:] = w_rot_m * e_r
        for i in range(6):
            for j in range(6):
                s = 0.0
                for k in range(n):
                    s += Jw[i, k] * Jw[j, k]
                JJt[i, j] = s
        v = k_null * (q_rest - q)
        # damped task step + rest-pose pull projected by the (near-)exact null space
        A[:] = JJt
        for i in range(6):
            A[i, i] += lam2
        dq = _times(Jw.T, _solve_spd(A, e)) + v
        A[:] = JJt
        for i in range(6):
            A[i, i] += 1e-9
        dq -= _times(Jw.T, _solve_spd(A, _times(Jw, v)))
        dq = np.minimum(np.maximum(dq, -dq_max_rad), dq_max_rad)
        q_new = np.minimum(np.maximum(q + dq, lower), upper)
        if used == iterations:
            # last step: predict the remaining error to first order instead of another
            # forward-kinematics pass (exact up to O(|dq|^2))
            de = _times(J, q_new - q)
            e_p = e_p - de[:3]
            e_r = e_r - de[3:]
            q = q_new
            break
        q = q_new
        J, p, R = _jacobian(fixed, axes, z_axes, q)
        e_p = p_target - p
        e_r[0], e_r[1], e_r[2] = log_relative_of(Rt, 0, R.reshape((1, 3, 3)), 0)
    return q, math.sqrt(_dot(e_p, e_p)), math.sqrt(_dot(e_r, e_r)), used


@kernel
def _dot(a: Array, b: Array) -> float:
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@kernel
def _times(M: Array, x: Array) -> Array:
    """M x (written out: BLAS for a 6x7 product costs more than the product)."""
    out = np.zeros(M.shape[0])
    for i in range(M.shape[0]):
        for k in range(M.shape[1]):
            out[i] += M[i, k] * x[k]
    return out


@dataclass(frozen=True)
class IKResult:
    """Result of one IK solve.

    Attributes:
        q_rad: (n,) joint positions [rad], within the limits.
        error_m: remaining position error [m] (first-order prediction after the last step).
        error_rad: remaining orientation error [rad] (likewise).
        iterations: iterations used.
    """

    q_rad: Array
    error_m: float
    error_rad: float
    iterations: int


class ArmChain:
    """A serial chain of revolute joints ending in a fixed tip frame (the palm).

    Args:
        fixed: (n + 1, 4, 4) fixed transforms: parent frame -> joint frame for each joint,
            then last joint -> tip.
        axes: (n, 3) joint axes in their joint frames.
        lower_rad: (n,) lower limits [rad].
        upper_rad: (n,) upper limits [rad].
        names: joint names.
    """

    def __init__(
        self, fixed: Array, axes: Array, lower_rad: Array, upper_rad: Array, names: tuple[str, ...]
    ) -> None:
        self.fixed = fixed
        self.axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
        self.lower_rad = lower_rad
        self.upper_rad = upper_rad
        self.names = names
        self._z_axes = bool(np.allclose(self.axes, [0.0, 0.0, 1.0]))

    @classmethod
    def from_urdf(
        cls, text: str, joint_names: tuple[str, ...], tip_joint: str | tuple[str, ...]
    ) -> ArmChain:
        """Read the chain `joint_names` (in order) then the fixed `tip_joint` (or several, in
        order from the last arm joint, composed into one tip transform) from URDF text."""
        model = UrdfModel.from_text(text)
        tips = (tip_joint,) if isinstance(tip_joint, str) else tuple(tip_joint)
        fixed: list[Array] = []
        axes: list[Array] = []
        lo: list[float] = []
        hi: list[float] = []
        for n in (*joint_names, *tips):
            j = model.joints.get(n)
            if j is None:
                raise InputError(f"URDF: {model.missing_joint(n)}")
            if n in tips:
                T = j.T_parent_joint
                fixed.append(T if n == tips[0] else fixed.pop() @ T)
                continue
            fixed.append(j.T_parent_joint)
            axes.append(j.axis)
            if j.limits is None:
                raise InputError(f"URDF joint {n!r} has no limits")
            lo.append(j.limits[0])
            hi.append(j.limits[1])
        return cls(
            np.array(fixed),
            np.array(axes, dtype=np.float64),
            np.array(lo),
            np.array(hi),
            tuple(joint_names),
        )

    @property
    def n(self) -> int:
        return len(self.names)

    def frames(self, q: Array) -> tuple[Array, Array, Array, Array]:
        """Joint origins (n, 3), joint axes (n, 3) in the base frame, tip p (3,), tip R (3, 3)."""
        return _frames(self.fixed, self.axes, self._z_axes, _vector(q))

    def fk(self, q: Array) -> tuple[Array, Array]:
        """Tip pose (p [m], R) at joint positions q [rad]."""
        _, _, p, R = self.frames(q)
        return p, R

    def jacobian(self, q: Array) -> tuple[Array, Array, Array]:
        """Geometric Jacobian (6, n) [linear; angular] of the tip, and the tip pose (p, R)."""
        return _jacobian(self.fixed, self.axes, self._z_axes, _vector(q))

    def ik(
        self,
        p_target_m: Array,
        R_target: Array,
        q0_rad: Array,
        q_rest_rad: Array,
        *,
        iterations: int = 8,
        tol_m: float = 2e-4,
        tol_rad: float = 2e-3,
        damping: float = 0.02,
        w_rot_m: float = 0.3,
        k_null: float = 0.2,
        dq_max_rad: float = 0.4,
    ) -> IKResult:
        """Damped-least-squares IK from q0 (see module docstring); never returns NaN.

        Args:
            p_target_m: (3,) target tip position [m].
            R_target: (3, 3) target tip orientation.
            q0_rad: (n,) start joint positions [rad] (warm start).
            q_rest_rad: (n,) null-space rest posture [rad].
            iterations: maximum iterations.
            tol_m: position tolerance [m].
            tol_rad: orientation tolerance [rad].
            damping: lambda of the damped pseudo-inverse [m].
            w_rot_m: weight of orientation against position [m/rad].
            k_null: null-space pull per iteration (0..1).
            dq_max_rad: largest joint change per iteration [rad].
        """
        q, err_m, err_rad, used = _ik(
            self.fixed, self.axes, self._z_axes, self.lower_rad, self.upper_rad,
            _vector(p_target_m), np.ascontiguousarray(R_target, dtype=np.float64),
            _vector(q0_rad), _vector(q_rest_rad), int(iterations), float(tol_m),
            float(tol_rad), float(damping), float(w_rot_m), float(k_null), float(dq_max_rad),
        )  # fmt: skip
        return IKResult(q, float(err_m), float(err_rad), int(used))


def _vector(x: Array) -> Array:
    """A float64, C-contiguous, writable 1-D copy or view (one compiled version)."""
    return as_input(x, (), 1)[0]


def compile_kernels() -> None:
    """Compile (or load from the cache) this module's compiled functions: `dev.sh` runs this
    at install, beside `arbitration.arbiters.compile_kernels`."""
    fixed = np.repeat(np.eye(4)[None], 2, axis=0)
    for axis in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]):  # the two forms of `frames`
        chain = ArmChain(fixed, np.array([axis]), np.array([-1.0]), np.array([1.0]), ("j",))
        chain.ik(np.zeros(3), np.eye(3), np.zeros(1), np.zeros(1))
