"""Scalar fast path of one unbatched tick, for the 30 Hz loop.

The numpy kernel in `arbiters.py` is written for a leading batch axis (thousands of
trajectories at once); on a single state its ~100 small-array operations cost ~120 us of
interpreter overhead. This module computes the same quantities with the same formulas (see
`allocation.py` for the maths, eq 1-8) on Python floats, several times faster for 6 + F
dimensions. `tests/test_arbitration_scalar.py` checks that both paths agree to 1e-9 on
random inputs in every mode, so the batched kernel stays the reference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState

Array = NDArray[np.float64]
Mat = list[list[float]]
Vec = list[float]

_SMALL = 1e-4
_NEAR_PI = math.pi - 1e-3


def log_rel(Ra: Mat, Rb: Mat) -> tuple[float, float, float]:
    """so3_log(Ra Rb^T) for 3x3 nested lists (same branches as `se3.so3_log`)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = Ra
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = Rb
    # M = Ra Rb^T: M_ij = row_i(Ra) . row_j(Rb)
    m00 = a00 * b00 + a01 * b01 + a02 * b02
    m11 = a10 * b10 + a11 * b11 + a12 * b12
    m22 = a20 * b20 + a21 * b21 + a22 * b22
    m01 = a00 * b10 + a01 * b11 + a02 * b12
    m10 = a10 * b00 + a11 * b01 + a12 * b02
    m02 = a00 * b20 + a01 * b21 + a02 * b22
    m20 = a20 * b00 + a21 * b01 + a22 * b02
    m12 = a10 * b20 + a11 * b21 + a12 * b22
    m21 = a20 * b10 + a21 * b11 + a22 * b12
    cos_t = (m00 + m11 + m22 - 1.0) * 0.5
    theta = math.acos(-1.0 if cos_t < -1.0 else 1.0 if cos_t > 1.0 else cos_t)
    vx, vy, vz = 0.5 * (m21 - m12), 0.5 * (m02 - m20), 0.5 * (m10 - m01)
    if theta < _SMALL:
        s = 1.0 + theta * theta / 6.0
    elif theta <= _NEAR_PI:
        s = theta / math.sin(theta)
    else:
        # a a^T = (sym(M) - cos I) / (1 - cos): column of the largest diagonal, sign from v.
        inv = 1.0 / (1.0 - cos_t)
        diag = ((m00 - cos_t) * inv, (m11 - cos_t) * inv, (m22 - cos_t) * inv)
        s01, s02, s12 = 0.5 * (m01 + m10) * inv, 0.5 * (m02 + m20) * inv, 0.5 * (m12 + m21) * inv
        k = max(range(3), key=diag.__getitem__)
        col = ((diag[0], s01, s02), (s01, diag[1], s12), (s02, s12, diag[2]))[k]
        n = math.sqrt(max(diag[k], 1e-300))
        ax, ay, az = col[0] / n, col[1] / n, col[2] / n
        if ax * vx + ay * vy + az * vz < 0.0:
            ax, ay, az = -ax, -ay, -az
        return theta * ax, theta * ay, theta * az
    return s * vx, s * vy, s * vz


def exp_times(w: Sequence[float], R: Mat) -> Mat:
    """so3_exp(w) @ R for one rotation vector (same series as `se3.so3_exp`)."""
    x, y, z = w
    t2 = x * x + y * y + z * z
    t = math.sqrt(t2)
    if t < _SMALL:
        a, b = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        a, b = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    # I + a K + b K^2 with K = hat(w); K^2 = w w^T - t2 I.
    E = (
        (1.0 + b * (x * x - t2), -a * z + b * x * y, a * y + b * x * z),
        (a * z + b * x * y, 1.0 + b * (y * y - t2), -a * x + b * y * z),
        (-a * y + b * x * z, a * x + b * y * z, 1.0 + b * (z * z - t2)),
    )
    c0, c1, c2 = zip(*R)
    return [[e[0] * c[0] + e[1] * c[1] + e[2] * c[2] for c in (c0, c1, c2)] for e in E]


def _diff(A: tuple[Vec, Mat, Vec], B: tuple[Vec, Mat, Vec]) -> Vec:
    pa, pb = A[0], B[0]
    return [
        pa[0] - pb[0],
        pa[1] - pb[1],
        pa[2] - pb[2],
        *log_rel(A[1], B[1]),
        *[x - y for x, y in zip(A[2], B[2])],
    ]


def _saturate(U: Vec, v_max: Vec) -> Vec:
    x, y, z, a, b, c = U[:6]
    nt = math.sqrt(x * x + y * y + z * z)
    nr = math.sqrt(a * a + b * b + c * c)
    ft = v_max[0] / nt if nt > v_max[0] else 1.0
    fr = v_max[3] / nr if nr > v_max[3] else 1.0
    out = [x * ft, y * ft, z * ft, a * fr, b * fr, c * fr]
    out += [-m if u < -m else m if u > m else u for u, m in zip(U[6:], v_max[6:])]
    return out


def _unit(d: Vec, eps: Vec) -> Vec:
    x, y, z, a, b, c = d[:6]
    f = d[6:]
    nt = math.sqrt(x * x + y * y + z * z)
    nr = math.sqrt(a * a + b * b + c * c)
    nf = math.sqrt(sum(v * v for v in f))
    it = 1.0 / nt if nt >= eps[0] else 0.0
    ir = 1.0 / nr if nr >= eps[3] else 0.0
    out = [x * it, y * it, z * it, a * ir, b * ir, c * ir]
    if f:
        i_f = 1.0 / nf if nf >= eps[6] else 0.0
        out += [v * i_f for v in f]
    return out


def kernel(
    states: Sequence[HandState],
    gains: Vec,
    v_max: Vec,
    eps: Vec,
    kappa: float,
    p: float,
    q: float,
    b: float,
    floor: float,
    dt: float,
    history: Vec,
) -> tuple[Vec, Vec, Vec, Vec, Vec, Vec, Vec]:
    """U_human, U_robot, P_human, P_robot, psi_human, psi_robot, B_raw for one tick.

    `states` are (human, human_prev, human_start, current, prev, start, goal), unbatched.
    """
    H, Hp, Hs, C, Cp, Cs, G = (
        (s.position.tolist(), s.rotation.tolist(), s.openness.tolist()) for s in states
    )
    d_goal_cur = _diff(G, C)
    d_h_hp = _diff(H, Hp)
    d_goal_h = _diff(G, H)

    U_r = _saturate([k * v for k, v in zip(gains, d_goal_cur)], v_max)
    inv_dt = 1.0 / dt
    U_h = _saturate([v * inv_dt for v in d_h_hp], v_max)

    # Denominators of eq (4): |goal - start| floored at eps (rotation entries unused).
    den = [max(abs(G[0][i] - Cs[0][i]), eps[i]) for i in range(3)] + [1.0, 1.0, 1.0]
    den += [max(abs(x - y), e) for x, y, e in zip(G[2], Cs[2], eps[6:])]
    erf, exp, cos = math.erf, math.exp, math.cos

    def allocation(d: Vec) -> Vec:
        out = [1.0 - erf(abs(v) / m) for v, m in zip(d, den)]
        out[3:6] = [exp(kappa * (cos(v) - 1.0)) for v in d[3:6]]
        return out

    P_r, P_h = allocation(d_goal_cur), allocation(d_goal_h)

    # eq (6), each agent with its own previous and start states.
    u_cp = _unit(_diff(C, Cp), eps)
    u_cs = _unit(_diff(C, Cs), eps)
    u_hp = _unit(d_h_hp, eps)
    u_hs = _unit(_diff(H, Hs), eps)
    psi_r = [u / m - a - s + h for u, m, a, s, h in zip(U_r, v_max, u_cp, u_cs, history)]
    psi_h = [u / m - a - s + h for u, m, a, s, h in zip(U_h, v_max, u_hp, u_hs, history)]

    # eq (7), normalised beta prime.
    scale = b * (q - 1.0) / p
    zm = (p - 1.0) / (q + 1.0)
    pm1, pq = p - 1.0, p + q
    c0 = pq * math.log1p(zm) - pm1 * math.log(zm)
    log, log1p = math.log, math.log1p
    B = []
    for ph, pr in zip(psi_h, psi_r):
        r = abs(pr)
        z = abs(ph) / ((r if r > floor else floor) * scale)
        z = z if z > 1e-300 else 1e-300
        B.append(exp(pm1 * log(z) - pq * log1p(z) + c0))
    return U_h, U_r, P_h, P_r, psi_h, psi_r, B


def integrate(X: HandState, U: Vec, dt: float) -> HandState:
    """Eq (2) for one state; same as `se3.integrate`."""
    p, g = X.position.tolist(), X.openness.tolist()
    R_next = exp_times((U[3] * dt, U[4] * dt, U[5] * dt), X.rotation.tolist())
    return HandState(
        np.array([p[0] + U[0] * dt, p[1] + U[1] * dt, p[2] + U[2] * dt]),
        np.array(R_next),
        np.array([min(max(gi + ui * dt, 0.0), 1.0) for gi, ui in zip(g, U[6:])]),
    )
