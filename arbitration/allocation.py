"""Eq (3)-(8): who gets how much authority, per dimension. The one implementation.

Arrays are dimension-first, (D, ...), D = 6 + F dimensions (x, y, z [m], rx, ry, rz [rad]
rotation-vector components in the base frame, then F fingers), with any batch after them:
the arbitration kernel calls these with rows of M trajectories (`se3` rows form), a batch of
one in the 30 Hz loop and thousands in the simulation study. (A single (D,) vector is the
same in either layout.)

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

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfc

from dsteleop.arbitration.se3 import FING, ROT, TRANS, norms_rows

Array = NDArray[np.float64]


def _col(v: Array, like: Array) -> Array:
    """A per-dimension vector (D',) shaped to broadcast over the batch axes of `like`."""
    return v.reshape(v.shape + (1,) * (like.ndim - 1))


def standard_alpha(p_goal: Array, p_cur: Array, p_start: Array, floor_m: float) -> Array:
    """Eq (3): one alpha per state from the L1 position distances, (3, ...) -> (...)."""
    num = np.abs(p_goal - p_cur).sum(0)
    den = np.maximum(np.abs(p_goal - p_start).sum(0), floor_m)
    return np.asarray(erfc(num / den))


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
    P = np.empty(np.broadcast_shapes(d_goal_agent.shape, d_goal_start.shape))
    for g in (TRANS, FING):
        den = np.maximum(np.abs(d_goal_start[g]), _col(floor[g], d_goal_start))
        P[g] = erfc(np.abs(d_goal_agent[g]) / den)
    P[ROT] = np.exp(kappa * (np.cos(d_goal_agent[ROT]) - 1.0))
    return P


def unit_directions(d: Array, threshold: Array) -> Array:
    """u(a, b) of eq (6) from d = diff(a, b) (6 + F, ...): each group over its norm, 0 below
    the group's threshold (`threshold[group start]`)."""
    out = np.zeros_like(d)
    for g in (TRANS, ROT, FING):
        dg = d[g]
        if dg.shape[0] == 0:
            continue
        n = norms_rows(dg)
        ok = n >= threshold[g.start]
        out[g] = np.where(ok, dg / np.where(ok, n, 1.0), 0.0)
    return out


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
    psi = U / _col(v_max, U) - unit_directions(d_cur_prev, still_step)
    psi -= unit_directions(d_cur_start, still_offset)
    if history_term is not None:
        psi += _col(np.asarray(history_term, dtype=np.float64), U)
    return psi


def willingness(
    psi_human: Array, psi_robot: Array, p: float, q: float, b: float, floor: float
) -> Array:
    """Eq (7): B in [0, 1], the beta-prime density at |psi_human| normalised at its mode."""
    sigma = np.maximum(np.abs(psi_robot), floor) * (b * (q - 1.0) / p)
    # z = 0 gives B = 0 (p > 1); the floor keeps log finite and exp underflows to exactly 0.
    z = np.maximum(np.abs(psi_human) / sigma, 1e-300)
    zm = (p - 1.0) / (q + 1.0)
    log_b = (p - 1.0) * np.log(z / zm) - (p + q) * (np.log1p(z) - np.log1p(zm))
    return np.asarray(np.exp(log_b))


def ds_alpha(P_robot: Array, P_human: Array, B: Array) -> Array:
    """Eq (8): alpha_i = clip((P(R_i) - P(H_i)) * B_i + P(H_i), 0, 1)."""
    return np.asarray(np.clip((P_robot - P_human) * B + P_human, 0.0, 1.0))
