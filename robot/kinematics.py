"""Forward kinematics, Jacobian and damped-least-squares IK of the arm, in numpy.

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

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import log_relative, so3_exp
from dsteleop.errors import InputError

Array = NDArray[np.float64]


def _rpy_to_R(r: float, p: float, y: float) -> Array:
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _origin(el: ET.Element) -> Array:
    T = np.eye(4)
    o = el.find("origin")
    if o is not None:
        xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
        T[:3, :3] = _rpy_to_R(*rpy)
        T[:3, 3] = xyz
    return T


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
        M[i] /= M[i, i]
        f = M[:, i].copy()
        f[i] = 0.0
        M -= f[:, None] * M[i]
    return M[:, n].copy()


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
    def from_urdf(cls, text: str, joint_names: tuple[str, ...], tip_joint: str) -> ArmChain:
        """Read the chain `joint_names` (in order) then the fixed `tip_joint` from URDF text."""
        root = ET.fromstring(text)
        joints = {j.get("name"): j for j in root.iter("joint")}
        fixed, axes, lo, hi = [], [], [], []
        for n in (*joint_names, tip_joint):
            j = joints.get(n)
            if j is None:
                raise InputError(f"URDF has no joint {n!r}")
            fixed.append(_origin(j))
            if n == tip_joint:
                continue
            ax = j.find("axis")
            axes.append(
                [float(v) for v in (ax.get("xyz", "1 0 0") if ax is not None else "1 0 0").split()]
            )
            lim = j.find("limit")
            if lim is None:
                raise InputError(f"URDF joint {n!r} has no limits")
            lo.append(float(lim.get("lower", "0")))
            hi.append(float(lim.get("upper", "0")))
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
        n = self.n
        if self._z_axes:
            c, s = np.cos(q), np.sin(q)
            Rj = np.zeros((n, 4, 4))
            Rj[:, 0, 0] = c
            Rj[:, 0, 1] = -s
            Rj[:, 1, 0] = s
            Rj[:, 1, 1] = c
            Rj[:, 2, 2] = 1.0
            Rj[:, 3, 3] = 1.0
        else:
            Rj = np.zeros((n, 4, 4))
            Rj[:, :3, :3] = so3_exp(self.axes * q[:, None])
            Rj[:, 3, 3] = 1.0
        A = self.fixed[:n] @ Rj
        T = np.empty((n + 1, 4, 4))
        T[0] = A[0]
        for k in range(1, n):
            T[k] = T[k - 1] @ A[k]
        T[n] = T[n - 1] @ self.fixed[n]
        origins = T[:n, :3, 3]
        # a joint's axis in the base frame: its local axis rotated by the joint frame
        axes = T[:n, :3, 2] if self._z_axes else np.einsum("kij,kj->ki", T[:n, :3, :3], self.axes)
        return origins, axes, T[n, :3, 3].copy(), T[n, :3, :3].copy()

    def fk(self, q: Array) -> tuple[Array, Array]:
        """Tip pose (p [m], R) at joint positions q [rad]."""
        _, _, p, R = self.frames(q)
        return p, R

    def jacobian(self, q: Array) -> tuple[Array, Array, Array]:
        """Geometric Jacobian (6, n) [linear; angular] of the tip, and the tip pose (p, R)."""
        origins, axes, p, R = self.frames(q)
        r = p - origins
        a0, a1, a2 = axes[:, 0], axes[:, 1], axes[:, 2]
        r0, r1, r2 = r[:, 0], r[:, 1], r[:, 2]
        J = np.empty((6, self.n))
        J[0] = a1 * r2 - a2 * r1  # axes x (p - origins), column per joint
        J[1] = a2 * r0 - a0 * r2
        J[2] = a0 * r1 - a1 * r0
        J[3:] = axes.T
        return J, p, R

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
        q = np.clip(np.asarray(q0_rad, dtype=np.float64), self.lower_rad, self.upper_rad)
        lam2 = damping * damping
        I6 = np.eye(6)
        used = 0
        J, p, R = self.jacobian(q)
        e_p = p_target_m - p
        e_r = log_relative(R_target, R)
        while True:
            converged = float(e_p @ e_p) < tol_m * tol_m and float(e_r @ e_r) < tol_rad * tol_rad
            if converged or used == iterations:
                break
            used += 1
            Jw = J.copy()
            Jw[3:] *= w_rot_m
            e = np.concatenate([e_p, w_rot_m * e_r])
            JJt = Jw @ Jw.T
            v = k_null * (q_rest_rad - q)
            # damped task step + rest-pose pull projected by the (near-)exact null space
            dq = Jw.T @ _solve_spd(JJt + lam2 * I6, e) + v
            dq -= Jw.T @ _solve_spd(JJt + 1e-9 * I6, Jw @ v)
            dq = np.clip(dq, -dq_max_rad, dq_max_rad)
            q_new = np.clip(q + dq, self.lower_rad, self.upper_rad)
            if used == iterations:
                # last step: predict the remaining error to first order instead of another
                # forward-kinematics pass (exact up to O(|dq|^2))
                de = J @ (q_new - q)
                e_p = e_p - de[:3]
                e_r = e_r - de[3:]
                q = q_new
                break
            q = q_new
            J, p, R = self.jacobian(q)
            e_p = p_target_m - p
            e_r = log_relative(R_target, R)
        return IKResult(q, float(np.linalg.norm(e_p)), float(np.linalg.norm(e_r)), used)
