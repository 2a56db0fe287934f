"""Scalar path of one unbatched tick, for the 30 Hz loop: the whole step on Python floats.

The batched kernel (`batched.py`) is written for a leading batch axis (thousands of
trajectories at once); on a single state every numpy call costs ~1 us of interpreter and
dispatch overhead, and a tick needs about a hundred of them. This module computes the same
quantities with the same formulas (the maths is stated once, in `allocation.py` and
`arbiters.py`, eq 1-8) on Python floats: kernel, DS moving windows and integration, so that one
tick touches numpy only to read its inputs and to build its outputs.
`tests/test_arbitration_perf_equivalence.py` checks that both paths, and a plain numpy
reference of the formulas, agree to 1e-9 on random and edge-case inputs in every mode.

Everything here is unrolled for the three translation and three rotation components; the F
finger components are loops. States are `(position, rotation, openness)` as lists (rotation
as three row lists), from `ndarray.tolist()`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

Mat = Sequence[Sequence[float]]
Vec = list[float]
State = tuple[Vec, Mat, Vec]

_SMALL = 1e-4
_NEAR_PI = math.pi - 1e-3


@dataclass(frozen=True)
class Constants:
    """Per-config constants of the scalar tick (built once per arbiter and finger count).

    Attributes:
        kt, kr, kf: gains K_r of translation, rotation, fingers [1/s].
        vt, vr, vf: velocity limits [m/s], [rad/s], [1/s].
        et, er, ef: eps floors of translation, rotation, fingers.
        kappa: von Mises concentration (eq 5).
        pm1, nq1: p - 1 and -(q + 1), the exponents of eq (7) written as
            B = k0 (z / (1 + z))^(p - 1) (1 + z)^-(q + 1), which stays finite for any z >= 0.
        scale: b (q - 1) / p, so that z = |psi_h| / sigma = |psi_h| / (max(|psi_r|, floor) scale).
        k0: (1 + z_m)^(p + q) / z_m^(p - 1), z_m = x_m / sigma, the mode normalisation.
        floor: psi_robot_floor of eq (7).
        eps_m: eps of the eq (3) denominator [m].
    """

    kt: float
    kr: float
    kf: float
    vt: float
    vr: float
    vf: float
    et: float
    er: float
    ef: float
    kappa: float
    pm1: float
    nq1: float
    scale: float
    k0: float
    floor: float
    eps_m: float


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


def exp_times(w: Sequence[float], R: Mat) -> list[list[float]]:
    """so3_exp(w) @ R for one rotation vector (same series as `se3.so3_exp`)."""
    x, y, z = w
    t2 = x * x + y * y + z * z
    t = math.sqrt(t2)
    if t < _SMALL:
        a, b = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        a, b = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    # I + a K + b K^2 with K = hat(w); K^2 = w w^T - t2 I.
    e00, e01, e02 = 1.0 + b * (x * x - t2), -a * z + b * x * y, a * y + b * x * z
    e10, e11, e12 = a * z + b * x * y, 1.0 + b * (y * y - t2), -a * x + b * y * z
    e20, e21, e22 = -a * y + b * x * z, a * x + b * y * z, 1.0 + b * (z * z - t2)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
    return [
        [e00 * r00 + e01 * r10 + e02 * r20, e00 * r01 + e01 * r11 + e02 * r21,
         e00 * r02 + e01 * r12 + e02 * r22],
        [e10 * r00 + e11 * r10 + e12 * r20, e10 * r01 + e11 * r11 + e12 * r21,
         e10 * r02 + e11 * r12 + e12 * r22],
        [e20 * r00 + e21 * r10 + e22 * r20, e20 * r01 + e21 * r11 + e22 * r21,
         e20 * r02 + e21 * r12 + e22 * r22],
    ]  # fmt: skip


Kernel = tuple[Vec, Vec, Vec, Vec, Vec, Vec, Vec]


def kernel(states: Sequence[State], c: Constants, dt: float, history: Vec | None) -> Kernel:
    """U_human, U_robot, P_human, P_robot, psi_human, psi_robot, B_raw of one tick.

    Args:
        states: (human, human_prev, human_start, current, prev, start, goal), each
            (position, rotation rows, openness) as lists.
        c: constants of the config.
        dt: tick length [s].
        history: the eq (6) history term (6 + F), or None for zeros.
    """
    H, Hp, Hs, C, Cp, Cs, G = states
    erf, exp, cos, sqrt = math.erf, math.exp, math.cos, math.sqrt
    RH, RC, RG = H[1], C[1], G[1]
    hx, hy, hz = H[0]
    cx, cy, cz = C[0]
    gx, gy, gz = G[0]
    sx, sy, sz = Cs[0]
    et, er, ef, kappa = c.et, c.er, c.ef, c.kappa
    kt, kr, kf = c.kt, c.kr, c.kf
    vt, vr, vf = c.vt, c.vr, c.vf
    inv_dt = 1.0 / dt

    # The six differences of the tick (translation t, rotation r, fingers below):
    # goal - cur, goal - hum, hum - hum_prev, hum - hum_start, cur - prev, cur - start.
    t_gc = (gx - cx, gy - cy, gz - cz)
    t_gh = (gx - hx, gy - hy, gz - hz)
    t_hp = (hx - Hp[0][0], hy - Hp[0][1], hz - Hp[0][2])
    t_hs = (hx - Hs[0][0], hy - Hs[0][1], hz - Hs[0][2])
    t_cp = (cx - Cp[0][0], cy - Cp[0][1], cz - Cp[0][2])
    t_cs = (cx - sx, cy - sy, cz - sz)
    r_gc = log_rel(RG, RC)
    r_gh = log_rel(RG, RH)
    r_hp = log_rel(RH, Hp[1])
    r_hs = log_rel(RH, Hs[1])
    r_cp = log_rel(RC, Cp[1])
    r_cs = log_rel(RC, Cs[1])

    # eq (4)/(5): P(R) from goal - cur, P(H) from goal - hum; denominators |goal - start|.
    dx, dy, dz = abs(gx - sx), abs(gy - sy), abs(gz - sz)
    dx, dy, dz = (dx if dx > et else et), (dy if dy > et else et), (dz if dz > et else et)
    P_r = [
        1.0 - erf(abs(t_gc[0]) / dx),
        1.0 - erf(abs(t_gc[1]) / dy),
        1.0 - erf(abs(t_gc[2]) / dz),
        exp(kappa * (cos(r_gc[0]) - 1.0)),
        exp(kappa * (cos(r_gc[1]) - 1.0)),
        exp(kappa * (cos(r_gc[2]) - 1.0)),
    ]
    P_h = [
        1.0 - erf(abs(t_gh[0]) / dx),
        1.0 - erf(abs(t_gh[1]) / dy),
        1.0 - erf(abs(t_gh[2]) / dz),
        exp(kappa * (cos(r_gh[0]) - 1.0)),
        exp(kappa * (cos(r_gh[1]) - 1.0)),
        exp(kappa * (cos(r_gh[2]) - 1.0)),
    ]

    # U_robot = sat(K_r (goal - cur)), U_human = sat((hum - hum_prev) / dt): translation and
    # rotation scaled by their norms, fingers clipped alone (se3.saturate).
    a, b, e = kt * t_gc[0], kt * t_gc[1], kt * t_gc[2]
    n = sqrt(a * a + b * b + e * e)
    f = vt / n if n > vt else 1.0
    U_r = [a * f, b * f, e * f]
    a, b, e = kr * r_gc[0], kr * r_gc[1], kr * r_gc[2]
    n = sqrt(a * a + b * b + e * e)
    f = vr / n if n > vr else 1.0
    U_r += (a * f, b * f, e * f)
    a, b, e = t_hp[0] * inv_dt, t_hp[1] * inv_dt, t_hp[2] * inv_dt
    n = sqrt(a * a + b * b + e * e)
    f = vt / n if n > vt else 1.0
    U_h = [a * f, b * f, e * f]
    a, b, e = r_hp[0] * inv_dt, r_hp[1] * inv_dt, r_hp[2] * inv_dt
    n = sqrt(a * a + b * b + e * e)
    f = vr / n if n > vr else 1.0
    U_h += (a * f, b * f, e * f)

    # Fingers: P and U one by one (each clipped alone); their four differences for eq (6).
    gH, gC, gG = H[2], C[2], G[2]
    f_hp = [x - y for x, y in zip(gH, Hp[2])]
    f_hs = [x - y for x, y in zip(gH, Hs[2])]
    f_cp = [x - y for x, y in zip(gC, Cp[2])]
    f_cs = [x - y for x, y in zip(gC, Cs[2])]
    for g_g, g_s, g_c, g_h, d_h in zip(gG, Cs[2], gC, gH, f_hp):
        den = abs(g_g - g_s)
        den = den if den > ef else ef
        d = g_g - g_c
        P_r.append(1.0 - erf(abs(d) / den))
        P_h.append(1.0 - erf(abs(g_g - g_h) / den))
        u = kf * d
        U_r.append(-vf if u < -vf else vf if u > vf else u)
        u = d_h * inv_dt
        U_h.append(-vf if u < -vf else vf if u > vf else u)

    # eq (6): u(a, b) = d / |d| per group and agent, 0 below the group's eps; kept as the
    # factors 1 / |d| of (hum - hum_prev, hum - hum_start, cur - prev, cur - start).
    inv = []
    for (x, y, z), (rx, ry, rz), fd in (
        (t_hp, r_hp, f_hp),
        (t_hs, r_hs, f_hs),
        (t_cp, r_cp, f_cp),
        (t_cs, r_cs, f_cs),
    ):
        n = sqrt(x * x + y * y + z * z)
        it = 1.0 / n if n >= et else 0.0
        n = sqrt(rx * rx + ry * ry + rz * rz)
        ir = 1.0 / n if n >= er else 0.0
        n = math.hypot(*fd)
        inv.append((it, ir, 1.0 / n if n >= ef else 0.0))
    i_hp, i_hs, i_cp, i_cs = inv
    iv = (1.0 / vt, 1.0 / vr, 1.0 / vf)
    psi_r = _psi(U_r, (t_cp, r_cp, f_cp), (t_cs, r_cs, f_cs), i_cp, i_cs, iv)
    psi_h = _psi(U_h, (t_hp, r_hp, f_hp), (t_hs, r_hs, f_hs), i_hp, i_hs, iv)
    if history is not None:
        psi_r = [x + h for x, h in zip(psi_r, history)]
        psi_h = [x + h for x, h in zip(psi_h, history)]

    # eq (7) B: the normalised beta prime at |psi_h| with reference max(|psi_r|, floor),
    # k0 (z / (1 + z))^(p - 1) (1 + z)^-(q + 1) for z = |psi_h| / sigma.
    k0, pm1, nq1, floor, scale = c.k0, c.pm1, c.nq1, c.floor, c.scale
    B = []
    for ph, pr in zip(psi_h, psi_r):
        r = abs(pr)
        z = abs(ph) / ((r if r > floor else floor) * scale)
        w = 1.0 + z
        B.append(k0 * (z / w) ** pm1 * w**nq1)
    return U_h, U_r, P_h, P_r, psi_h, psi_r, B


Diff = tuple[Sequence[float], Sequence[float], Sequence[float]]


def _psi(
    U: Vec,
    d_prev: Diff,
    d_start: Diff,
    k_prev: tuple[float, float, float],
    k_start: tuple[float, float, float],
    inv_vmax: tuple[float, float, float],
) -> Vec:
    """Eq (6) for one agent without the history term: U / v_max - u(., prev) - u(., start).

    Args:
        U: the agent's velocity (6 + F).
        d_prev, d_start: its differences to its previous and start states, (t, r, f) groups.
        k_prev, k_start: 1 / |d| of each group, 0 below the group's eps.
        inv_vmax: 1 / v_max of translation, rotation, fingers.
    """
    (tp, rp, fp), (ts, rs, fs) = d_prev, d_start
    (pt, pr, pf), (st, sr, sf) = k_prev, k_start
    it, ir, i_f = inv_vmax
    psi = [
        U[0] * it - tp[0] * pt - ts[0] * st,
        U[1] * it - tp[1] * pt - ts[1] * st,
        U[2] * it - tp[2] * pt - ts[2] * st,
        U[3] * ir - rp[0] * pr - rs[0] * sr,
        U[4] * ir - rp[1] * pr - rs[1] * sr,
        U[5] * ir - rp[2] * pr - rs[2] * sr,
    ]
    psi += [u * i_f - x * pf - y * sf for u, x, y in zip(U[6:], fp, fs)]
    return psi


def standard_alpha(goal: Vec, cur: Vec, start: Vec, eps_m: float) -> float:
    """Eq (3) on one state (same as `allocation.standard_alpha`)."""
    num = abs(goal[0] - cur[0]) + abs(goal[1] - cur[1]) + abs(goal[2] - cur[2])
    den = abs(goal[0] - start[0]) + abs(goal[1] - start[1]) + abs(goal[2] - start[2])
    return 1.0 - math.erf(num / (den if den > eps_m else eps_m))


def ds_filter(
    P_r: Vec,
    P_h: Vec,
    B_raw: Vec,
    alpha_rows: tuple[tuple[float, ...], ...],
    B_rows: tuple[tuple[float, ...], ...],
    count: int,
) -> tuple[Vec, Vec, tuple[tuple[float, ...], ...], tuple[tuple[float, ...], ...]]:
    """Eq (8) with the moving windows.

    Args:
        P_r, P_h, B_raw: this tick's allocations and raw willingness.
        alpha_rows, B_rows: the windows, W rows of D samples in slot order (not modified).
        count: alpha samples seen before this tick.

    Returns:
        (alpha, B, alpha_rows, B_rows): the filtered values and the new windows (this tick's
        row in slot count % W, the other rows shared).
    """
    W = len(B_rows)
    slot = count % W
    B_rows = (*B_rows[:slot], tuple(B_raw), *B_rows[slot + 1 :])
    inv_w = 1.0 / W
    # Window sums in slot order, as numpy sums a (W, D) buffer over its first axis.
    B = [s * inv_w for s in map(sum, zip(*B_rows))]
    a_raw = tuple(
        [
            0.0 if (a := (r - h) * b + h) < 0.0 else 1.0 if a > 1.0 else a
            for r, h, b in zip(P_r, P_h, B)
        ]
    )
    alpha_rows = (*alpha_rows[:slot], a_raw, *alpha_rows[slot + 1 :])
    n = count + 1 if count < W else W
    alpha = [s / n for s in map(sum, zip(*alpha_rows))]
    return alpha, B, alpha_rows, B_rows


def finish(
    X: State, U_h: Vec, U_r: Vec, alpha: Vec, dt: float
) -> tuple[Vec, tuple[Vec, list[list[float]], Vec]]:
    """Eq (1) and (2): U_out and the integrated next state (same as `se3.integrate`)."""
    U_out = [h + a * (r - h) for h, a, r in zip(U_h, alpha, U_r)]
    p, R, g = X
    R_next = exp_times((U_out[3] * dt, U_out[4] * dt, U_out[5] * dt), R)
    p_next = [p[0] + U_out[0] * dt, p[1] + U_out[1] * dt, p[2] + U_out[2] * dt]
    g_next = [
        0.0 if (v := gi + ui * dt) < 0.0 else 1.0 if v > 1.0 else v for gi, ui in zip(g, U_out[6:])
    ]
    return U_out, (p_next, R_next, g_next)
