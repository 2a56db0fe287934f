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
`advance_rows` skips the bound in that case.

The functions work in the rows form of `se3` (dimension-first, batch flattened last);
`advance_reference` also takes and returns the usual layout for callers outside the kernel.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.se3 import (
    HandState,
    StateRows,
    exp_rows,
    integrate_rows,
    log_relative_rows,
    matmul_rows,
    norms_rows,
    saturate_rows,
    to_rows,
)

Array = NDArray[np.float64]


def robot_action(d_goal_current: Array, cfg: ArbitrationConfig) -> Array:
    """U_robot [m/s, rad/s, 1/s], (6 + F, M), from d = diff(X_goal, X_current)."""
    F = d_goal_current.shape[0] - 6
    return saturate_rows(cfg.gains(F)[:, None] * d_goal_current, cfg.v_max(F))


def human_action(d_human_prev: Array, dt: float, cfg: ArbitrationConfig) -> Array:
    """U_human [m/s, rad/s, 1/s], (6 + F, M), from d = diff(X_human, X_human_prev)."""
    return saturate_rows(d_human_prev / dt, cfg.v_max(d_human_prev.shape[0] - 6))


def advance_rows(
    X_ref: StateRows, X_current: StateRows, U: Array, dt: float, cfg: ArbitrationConfig
) -> StateRows:
    """Eq (2) on the bounded reference (module docstring), rows form."""
    X = integrate_rows(X_ref, U, dt)
    if (
        X_ref is X_current
        and cfg.v_max_mps * dt <= cfg.max_lead_m
        and (cfg.w_max_radps * dt <= cfg.max_lead_rad)
    ):
        return X  # one saturated tick from the achieved state stays inside the bound
    dp = X.p - X_current.p
    p = X_current.p + dp * np.minimum(1.0, cfg.max_lead_m / np.maximum(norms_rows(dp), 1e-300))
    e = log_relative_rows(X.R, X_current.R)
    a = norms_rows(e)
    over = a > cfg.max_lead_rad
    R = X.R
    if over.any():
        k = np.flatnonzero(over)
        R = R.copy()
        w = e[:, k] * (cfg.max_lead_rad / a[k])
        R[..., k] = matmul_rows(exp_rows(w), X_current.R[..., k])
    return StateRows(p, R, X.g)


def advance_reference(
    X_ref: HandState, X_current: HandState, U: Array, dt: float, cfg: ArbitrationConfig
) -> HandState:
    """Eq (2) on the bounded reference, for states in the usual layout, U (..., 6 + F)."""
    batch = np.broadcast_shapes(X_ref.batch, X_current.batch, U.shape[:-1])
    U_rows = to_rows(np.broadcast_to(U, (*batch, U.shape[-1])), math.prod(batch), 1)
    X_ref_rows = StateRows.of(X_ref, batch=batch)
    X_cur_rows = StateRows.of(X_current, batch=batch)
    rows = advance_rows(X_ref_rows, X_cur_rows, U_rows, dt, cfg)
    return rows.state(batch)
