"""The two actions that eq (1) blends, and eq (2) with its bounded reference.

The robot's policy is goal seeking, the shortest distance and the smallest angle:

    U_robot = sat(K_r * diff(X_goal, X_current))

The operator's action is the motion of the mapped hand (a rate mapping, not a pull towards
where the hand is), so in manual mode the robot moves exactly as the hand moves:

    U_human = sat(diff(X_human, X_human_prev) / dt)

Eq (2) integrates the blended action from the commanded reference X_ref, the previous
tick's X_next, not from the achieved pose X_current: a position-controlled robot lags its
command by a little every tick, and integrating from where it got to would lose that lag
each tick (in a first version the robot fell a third short of the hand's motion in manual
mode). The reference stays within `max_lead_m` / `max_lead_rad` of the achieved pose, so a
robot blocked by the table does not wind it up:

    X'     = integrate(X_ref, U, dt)
    p_next = p_cur + (p' - p_cur) * min(1, max_lead_m / |p' - p_cur|)
    R_next = exp(e * min(1, max_lead_rad / |e|)) R_cur,   e = log(R' R_cur^T)
    g_next = g'

A kinematic plant (the simulation study) passes X_ref = X_current: eq (2) is then the plain
integration, because one tick of saturated motion (v_max dt, w_max dt) cannot leave the
bound when it is within it, as it is by default (8 mm, 0.03 rad against 3 cm, 0.25 rad);
the kernel skips the bound in that case (`bound_needed`).

The actions, eq (2) and its bound are compiled functions of one state (`jit.kernel`), which
the arbitration kernel calls per row; `advance_reference` is their loop over a batch in the usual
layout, for the loop's halt ramp.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.jit import as_input, kernel
from dsteleop.arbitration.se3 import (
    HandState,
    batch_of,
    integrate_into,
    log_relative_of,
    rotate_into,
    row,
    saturate_into,
    state_input,
)

Array = NDArray[np.float64]


@kernel
def robot_action_into(d_goal_current: Array, a: int, gains: Array, v_max: Array, out: Array,
                      m: int) -> None:  # fmt: skip
    """U_robot [m/s, rad/s, 1/s] (6 + F,) into out[m] from d = diff(X_goal, X_current), row a."""
    for i in range(d_goal_current.shape[1]):
        out[m, i] = gains[i] * d_goal_current[a, i]
    saturate_into(out, m, v_max, out, m)


@kernel
def human_action_into(d_human_prev: Array, a: int, dt: float, v_max: Array, out: Array,
                      m: int) -> None:  # fmt: skip
    """U_human [m/s, rad/s, 1/s] (6 + F,) into out[m] from d = diff(X_human, X_human_prev),
    row a."""
    for i in range(d_human_prev.shape[1]):
        out[m, i] = d_human_prev[a, i] / dt
    saturate_into(out, m, v_max, out, m)


@kernel
def bound_into(
    p_cur: Array, R_cur: Array, c: int, max_lead_m: float, max_lead_rad: float,
    out_p: Array, out_R: Array, m: int,
) -> None:  # fmt: skip
    """The bound of eq (2) (module docstring): the integrated reference in row m of out_p and
    out_R, brought within the leads of the achieved state in row c."""
    d0 = out_p[m, 0] - p_cur[c, 0]
    d1 = out_p[m, 1] - p_cur[c, 1]
    d2 = out_p[m, 2] - p_cur[c, 2]
    scale = min(1.0, max_lead_m / max(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), 1e-300))
    out_p[m, 0] = p_cur[c, 0] + d0 * scale
    out_p[m, 1] = p_cur[c, 1] + d1 * scale
    out_p[m, 2] = p_cur[c, 2] + d2 * scale
    e0, e1, e2 = log_relative_of(out_R, m, R_cur, c)
    a = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    if a > max_lead_rad:
        k = max_lead_rad / a
        rotate_into(e0 * k, e1 * k, e2 * k, R_cur, c, out_R, m)


def bound_needed(has_reference: bool, dt: float, cfg: ArbitrationConfig) -> bool:
    """Whether eq (2) must bound the reference: always when it integrates from a reference of
    its own; from the achieved state only if one saturated tick can leave the bound."""
    return has_reference or not (
        cfg.v_max_mps * dt <= cfg.max_lead_m and cfg.w_max_radps * dt <= cfg.max_lead_rad
    )


@kernel
def _advance_batch(
    p_ref: Array, R_ref: Array, g_ref: Array, p_cur: Array, R_cur: Array, U: Array,
    dt: float, max_lead_m: float, max_lead_rad: float, M: int,
) -> tuple[Array, Array, Array]:  # fmt: skip
    out_p, out_R, out_g = np.empty((M, 3)), np.empty((M, 3, 3)), np.empty((M, g_ref.shape[1]))
    for m in range(M):
        integrate_into(
            p_ref, R_ref, g_ref, row(p_ref.shape[0], m), U, row(U.shape[0], m), dt,
            out_p, out_R, out_g, m,
        )  # fmt: skip
        bound_into(p_cur, R_cur, row(p_cur.shape[0], m), max_lead_m, max_lead_rad, out_p, out_R, m)
    return out_p, out_R, out_g


def advance_reference(
    X_ref: HandState, X_current: HandState, U: Array, dt: float, cfg: ArbitrationConfig
) -> HandState:
    """Eq (2) on the bounded reference, for states in the usual layout, U (..., 6 + F)."""
    U = np.asarray(U, dtype=np.float64)
    batch = batch_of(X_ref.batch, X_current.batch, U.shape[:-1])
    p_cur, R_cur, _ = state_input(X_current, batch)
    p, R, g = _advance_batch(
        *state_input(X_ref, batch), p_cur, R_cur, as_input(U, batch, 1), float(dt),
        float(cfg.max_lead_m), float(cfg.max_lead_rad), math.prod(batch),
    )  # fmt: skip
    return HandState(p.reshape(*batch, 3), R.reshape(*batch, 3, 3), g.reshape(*batch, -1))
