"""Eq (3)-(8): who gets how much authority, per dimension. The one implementation.

Each equation is one compiled function of one dimension of one state (`jit.kernel`), which
the arbitration kernel (`arbiters.py`) calls for every row and dimension of a tick. The
array functions after them apply the same functions to arrays that are dimension-first,
(D, ...), D = 6 + F dimensions (x, y, z [m], rx, ry, rz [rad] rotation-vector components
in the base frame, then F fingers), with any batch after them.

Standard controller (S), eq (3), one alpha for every dimension from position only:

    alpha = 1 - erf(|p_goal - p_cur|_1 / max(|p_goal - p_start|_1, floor))

Expected control allocation of agent A in {H: X_human, R: X_current}, eq (4) and (5):

    translation, fingers:  P(A_i) = 1 - erf(|goal_i - agent_i| / max(|goal_i - start_i|, floor_i))
    rotation:              P(A_i) = exp(kappa * (cos(e_i) - 1)),  e = log(R_goal R_agent^T)

(the von Mises density of eq (5) divided by its peak, so P is in (0, 1] and 1 at the goal).
The floor is a task-scale length (`alloc_floor_m`, 2 cm; `alloc_floor_openness`), so that in
a dimension whose goal equals its start P stays a smooth function of the distance.

Expected speed change, eq (6), per agent and dimension, unitless:

    psi_i = U_i / vmax_i - u(cur, prev)_i - u(cur, start)_i + mean_n u(terminal_n, start_n)_i

with u(a, b) = diff(a, b) / |diff(a, b)|_2 over the dimension's group (translation, rotation,
fingers) and 0 when that norm is below the group's threshold: for u(cur, prev), a difference
one tick apart, the threshold is a speed times dt (`still_*_per_s` / `still_speed_mps` /
`still_rate_radps`); for u(cur, start) and the previous attempts, a distance
(`still_distance_m`, `still_angle_rad`, `still_openness`). The states are the agent's own: the
hand's poses for psi_human, the robot's for psi_robot.

Willingness, eq (7): the beta-prime density with shapes p, q and scale
sigma = b * r * (q - 1) / p, whose mean is b * r, evaluated at |psi_human| and divided by its
value at the mode x_m = sigma * (p - 1) / (q + 1), so B is in [0, 1] and 1 at the mode:

    B = (x / x_m)^(p - 1) * ((1 + x_m / sigma) / (1 + x / sigma))^(p + q)

The reference is r = max(|psi_robot|, psi_robot_floor): where the robot expects no speed change
the density would collapse onto 0; the floor keeps B finite and makes an operator who holds
still unwilling (B -> 0), which hands control back to them.

Dimension-specific alpha, eq (8): alpha_i = clip((P(R_i) - P(H_i)) * B_i + P(H_i), 0, 1).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.jit import kernel
from dsteleop.arbitration.se3 import group_norm

Array = NDArray[np.float64]

# --- compiled: one dimension of one state (the arbitration kernel calls these) -----------


@kernel
def standard_alpha_of(l1_goal_cur: float, l1_goal_start: float, floor_m: float) -> float:
    """Eq (3) from the L1 position distances goal-current and goal-start [m]."""
    return math.erfc(l1_goal_cur / max(l1_goal_start, floor_m))


@kernel
def allocation_linear(d_goal_agent: float, d_goal_start: float, floor: float) -> float:
    """Eq (4): P(A_i) of a translation or finger dimension."""
    return math.erfc(abs(d_goal_agent) / max(abs(d_goal_start), floor))


@kernel
def allocation_rotation(e: float, kappa: float) -> float:
    """Eq (5): P(A_i) of a rotation dimension, e the component of log(R_goal R_agent^T)."""
    return math.exp(kappa * (math.cos(e) - 1.0))


@kernel
def unit_directions_into(d: Array, a: int, threshold: Array, out: Array, m: int) -> None:
    """u(A, B) of eq (6) into out[m] from row a of d, diff(A, B) (6 + F,): each group over its
    norm, 0 below the group's threshold (`threshold[group start]`)."""
    D = d.shape[1]
    _unit_into(d, a, 0, 3, threshold[0], out, m)
    _unit_into(d, a, 3, 6, threshold[3], out, m)
    if D > 6:
        _unit_into(d, a, 6, D, threshold[6], out, m)


@kernel
def _unit_into(d: Array, a: int, start: int, stop: int, threshold: float, out: Array,
               m: int) -> None:  # fmt: skip
    """One group of `unit_directions_into`."""
    n = group_norm(d, a, start, stop)
    ok = n >= threshold
    for i in range(start, stop):
        out[m, i] = d[a, i] / n if ok else 0.0


@kernel
def speed_change_of(
    U: float, v_max: float, u_cur_prev: float, u_cur_start: float, history: float
) -> float:
    """Eq (6): psi_i from the action, its limit and the unit directions of dimension i."""
    return U / v_max - u_cur_prev - u_cur_start + history


@kernel
def willingness_of(psi_human: float, psi_robot: float, p: float, q: float, b: float,
                   floor: float) -> float:  # fmt: skip
    """Eq (7): B in [0, 1], the beta-prime density at |psi_human| normalised at its mode."""
    sigma = max(abs(psi_robot), floor) * (b * (q - 1.0) / p)
    # z = 0 gives B = 0 (p > 1); the floor keeps log finite and exp underflows to exactly 0.
    z = max(abs(psi_human) / sigma, 1e-300)
    zm = (p - 1.0) / (q + 1.0)
    return math.exp((p - 1.0) * math.log(z / zm) - (p + q) * math.log((1.0 + z) / (1.0 + zm)))


@kernel
def ds_alpha_of(P_robot: float, P_human: float, B: float) -> float:
    """Eq (8): alpha_i = clip((P(R_i) - P(H_i)) * B_i + P(H_i), 0, 1)."""
    return min(max((P_robot - P_human) * B + P_human, 0.0), 1.0)


# --- the same, over arrays (D, ...): loops of the functions above --------------------------


def _flat(*arrays: Array) -> tuple[tuple[int, ...], list[Array]]:
    """Arrays broadcast to one shape (D, ...), flattened to (D, N), contiguous."""
    shape = np.broadcast_shapes(*(np.shape(a) for a in arrays))
    out = [
        np.array(np.broadcast_to(np.asarray(a, dtype=np.float64), shape), order="C").reshape(
            shape[0], -1
        )
        for a in arrays
    ]
    return shape, out


@kernel
def _standard_alpha_rows(d_cur: Array, d_start: Array, floor_m: float) -> Array:
    out = np.empty(d_cur.shape[1])
    for n in range(d_cur.shape[1]):
        num = abs(d_cur[0, n]) + abs(d_cur[1, n]) + abs(d_cur[2, n])
        den = abs(d_start[0, n]) + abs(d_start[1, n]) + abs(d_start[2, n])
        out[n] = standard_alpha_of(num, den, floor_m)
    return out


def standard_alpha(p_goal: Array, p_cur: Array, p_start: Array, floor_m: float) -> Array:
    """Eq (3): one alpha per state from the L1 position distances, (3, ...) -> (...)."""
    shape, (g, c, s) = _flat(p_goal, p_cur, p_start)
    return _standard_alpha_rows(g - c, g - s, float(floor_m)).reshape(shape[1:])


@kernel
def _allocation_rows(d_agent: Array, d_start: Array, floor: Array, kappa: float) -> Array:
    out = np.empty_like(d_agent)
    for i in range(d_agent.shape[0]):
        for n in range(d_agent.shape[1]):
            if 3 <= i < 6:
                out[i, n] = allocation_rotation(d_agent[i, n], kappa)
            else:
                out[i, n] = allocation_linear(d_agent[i, n], d_start[i, n], floor[i])
    return out


def expected_allocation(
    d_goal_agent: Array, d_goal_start: Array, floor: Array, kappa: float
) -> Array:
    """Eq (4)/(5): P(A_i) for every dimension, (6 + F, ...).

    Args:
        d_goal_agent: diff(X_goal, X_agent), (6 + F, ...).
        d_goal_start: diff(X_goal, X_start), broadcastable to it; rotation entries unused.
        floor: (6 + F,) floors of the denominators (rotation entries unused).
        kappa: von Mises concentration.
    """
    shape, (a, s) = _flat(d_goal_agent, d_goal_start)
    floor_col = np.ascontiguousarray(floor, dtype=np.float64)
    return _allocation_rows(a, s, floor_col, float(kappa)).reshape(shape)


@kernel
def _unit_directions_rows(d: Array, threshold: Array) -> Array:
    """u of each row of d (N, 6 + F)."""
    out = np.empty_like(d)
    for n in range(d.shape[0]):
        unit_directions_into(d, n, threshold, out, n)
    return out


def unit_directions(d: Array, threshold: Array) -> Array:
    """u(a, b) of eq (6) from d = diff(a, b) (6 + F, ...): each group over its norm, 0 below
    the group's threshold (`threshold[group start]`)."""
    shape, (dd,) = _flat(d)
    thr = np.ascontiguousarray(threshold, dtype=np.float64)
    return _unit_directions_rows(np.ascontiguousarray(dd.T), thr).T.reshape(shape)


def expected_speed_change(
    U: Array,
    v_max: Array,
    d_cur_prev: Array,
    d_cur_start: Array,
    history_term: Array | None,
    still_step: Array,
    still_offset: Array,
) -> Array:
    """Eq (6): psi, (6 + F, ...), for one agent or for several along a batch axis.

    Args:
        U: the agent's action; v_max: (6 + F,) the velocity limits.
        d_cur_prev, d_cur_start: the agent's differences to its previous and start states.
        history_term: (6 + F,) the previous attempts' mean direction, or None.
        still_step: (6 + F,) thresholds of the one-tick difference (speed times dt).
        still_offset: (6 + F,) thresholds of the difference from the start.
    """
    u_prev = unit_directions(d_cur_prev, still_step)
    u_start = unit_directions(d_cur_start, still_offset)
    D = u_prev.shape[0]
    h = np.zeros(D) if history_term is None else np.asarray(history_term, dtype=np.float64)
    shape, (Uf, up, us, hf, vf) = _flat(
        U, u_prev, u_start, h.reshape(D, *([1] * (u_prev.ndim - 1))),
        np.reshape(v_max, (D, *([1] * (u_prev.ndim - 1)))),
    )  # fmt: skip
    return _speed_change_rows(Uf, vf, up, us, hf).reshape(shape)


@kernel
def _speed_change_rows(U: Array, v_max: Array, u_prev: Array, u_start: Array, h: Array) -> Array:
    out = np.empty_like(U)
    for i in range(U.shape[0]):
        for n in range(U.shape[1]):
            out[i, n] = speed_change_of(U[i, n], v_max[i, n], u_prev[i, n], u_start[i, n], h[i, n])
    return out


@kernel
def _willingness_rows(
    psi_h: Array, psi_r: Array, p: float, q: float, b: float, floor: float
) -> Array:
    out = np.empty(psi_h.shape)
    for n in range(psi_h.shape[0]):
        out[n] = willingness_of(psi_h[n], psi_r[n], p, q, b, floor)
    return out


def willingness(
    psi_human: Array, psi_robot: Array, p: float, q: float, b: float, floor: float
) -> Array:
    """Eq (7): B in [0, 1], the beta-prime density at |psi_human| normalised at its mode."""
    shape = np.broadcast_shapes(np.shape(psi_human), np.shape(psi_robot))
    h = np.array(np.broadcast_to(np.asarray(psi_human, dtype=np.float64), shape), order="C")
    r = np.array(np.broadcast_to(np.asarray(psi_robot, dtype=np.float64), shape), order="C")
    args = (float(p), float(q), float(b), float(floor))
    return _willingness_rows(h.reshape(-1), r.reshape(-1), *args).reshape(shape)


@kernel
def _ds_alpha_rows(P_r: Array, P_h: Array, B: Array) -> Array:
    out = np.empty(P_r.shape)
    for n in range(P_r.size):
        out[n] = ds_alpha_of(P_r[n], P_h[n], B[n])
    return out


def ds_alpha(P_robot: Array, P_human: Array, B: Array) -> Array:
    """Eq (8): alpha_i = clip((P(R_i) - P(H_i)) * B_i + P(H_i), 0, 1)."""
    shape = np.broadcast_shapes(np.shape(P_robot), np.shape(P_human), np.shape(B))
    r, h, b = (
        np.array(np.broadcast_to(np.asarray(x, dtype=np.float64), shape), order="C").reshape(-1)
        for x in (P_robot, P_human, B)
    )
    return _ds_alpha_rows(r, h, b).reshape(shape)
