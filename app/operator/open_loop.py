"""A seeded, stochastic, goal-directed synthetic operator: pure numpy, no I/O, no clock.

It produces the trajectory of a mapped hand (`HandState`: palm position [m], rotation, finger
openness) from a start state to the operator's own goal at a fixed tick `dt`, with human-like
strategies. It is open loop: it does not watch the robot (as the sampled trajectories of the
paper's simulation study, Section IV-A). Same generator state, same trajectory, bit for bit.

Model (docs/sim.md says why each part is there). A movement phase tau in [0, 1] drives every
component c (a translational axis, the rotation, the fingers) through its own window
[on_c, off_c] with a minimum-jerk profile

    s_c(tau) = m((tau - on_c) / (off_c - on_c)),   m(u) = 10 u^3 - 15 u^4 + 6 u^5, u in [0, 1]

    p(tau) = p_0 + s_x (p_T - p_0)_x e_x + ... + w_p(tau)            (per axis)
    R(tau) = exp(w_R(tau)) exp(s_R(tau) log(R_T R_0^T)) R_0           (geodesic, base frame)
    g(tau) = g_0 + s_g(tau) (g_T - g_0)

where T marks the target (the goal plus the operator's endpoint error) and w_p, w_R are a
smooth wander (knots of Gaussian noise, cubic-interpolated, times the envelope sin(pi tau), so
it vanishes at both ends). Strategies are the windows:

    * lead axes (e.g. y before x): with probability `lead_probability` the lead axes move on
      [0, lead_end] and the others on [lead_end - overlap, 1] (an L-shaped, side approach);
      otherwise all translational axes move together on [0, 1] (a straight reach);
    * late rotation: the rotation moves on [rotation_onset, rotation_end];
    * fingers: on [finger_onset, 1] (close or open at the end of the reach).

Timing maps tau to time: the phase rate is a smooth random speed multiplier
exp(speed_variability * z(tau)) (z from knots, unit variance), scaled so the movement lasts
`move_s` = max(path / speed, angle / rot_speed / rotation window, min_move_s) seconds, plus
pauses (at random phases, random lengths), a reaction time before and a hold after. When the
sampled hand would exceed the speed caps (the robot's velocity limits: the operator should not
be clipped by the saturation of U_human) the movement is stretched until it does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState, so3_exp, so3_log
from dsteleop.errors import ConfigError, ContractError

Array = NDArray[np.float64]
Interval = tuple[float, float]

_N_KNOTS = 7  # knots of the speed and wander noise over the phase
_PHASE_GRID = 201  # samples of tau used to build the time map


@dataclass(frozen=True)
class OperatorStrategy:
    """Distributions of the operator's strategy; an interval (lo, hi) is drawn uniformly.

    Attributes:
        speed_mps: mean translational speed over the path [m/s].
        rot_speed_radps: mean angular speed within the rotation window [rad/s].
        min_move_s: shortest movement [s].
        lead_axes: translational axes moved first (0 = x, 1 = y, 2 = z); empty for none.
        lead_probability: share of trajectories that use the lead-axes strategy.
        lead_end: phase at which the lead axes arrive.
        overlap: phase before lead_end at which the other axes start.
        rotation_onset: phase at which the rotation starts (late correction when high).
        rotation_end: phase at which the rotation ends.
        finger_onset: phase at which the fingers start to move.
        speed_variability: standard deviation of the log speed multiplier.
        pause_rate: expected pauses per second of movement [1/s].
        pause_s: length of one pause [s].
        reaction_s: still time before the movement [s].
        hold_s: still time at the target after the movement [s].
        wander_m: standard deviation of the mid-movement positional wander [m].
        wander_rad: standard deviation of the mid-movement rotational wander [rad].
        endpoint_sd_m: standard deviation of the final position error per axis [m].
        endpoint_sd_rad: standard deviation of the final rotation error per axis [rad].
        noise_dims: the six dimensions (x, y, z, roll, pitch, yaw) that wander and endpoint
            errors act on; e.g. (True, True, False, False, False, True) for a planar task.
        v_cap_mps: translational speed cap [m/s] (the robot's limit).
        w_cap_radps: angular speed cap [rad/s] (the robot's limit).
    """

    speed_mps: Interval = (0.10, 0.20)
    rot_speed_radps: Interval = (0.4, 0.8)
    min_move_s: float = 1.5
    lead_axes: tuple[int, ...] = (1,)
    lead_probability: float = 0.8
    lead_end: Interval = (0.45, 0.65)
    overlap: Interval = (0.05, 0.3)
    rotation_onset: Interval = (0.45, 0.75)
    rotation_end: Interval = (0.9, 1.0)
    finger_onset: Interval = (0.8, 0.95)
    speed_variability: float = 0.3
    pause_rate: float = 0.15
    pause_s: Interval = (0.2, 0.7)
    reaction_s: Interval = (0.1, 0.4)
    hold_s: Interval = (0.4, 0.8)
    wander_m: float = 0.006
    wander_rad: float = 0.03
    endpoint_sd_m: float = 0.004
    endpoint_sd_rad: float = 0.03
    noise_dims: tuple[bool, bool, bool, bool, bool, bool] = (True,) * 6
    v_cap_mps: float = 0.24
    w_cap_radps: float = 0.95

    def __post_init__(self) -> None:
        for name in (
            "speed_mps", "rot_speed_radps", "lead_end", "overlap", "rotation_onset",
            "rotation_end", "finger_onset", "pause_s", "reaction_s", "hold_s",
        ):  # fmt: skip
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
                raise ConfigError(f"{name} must be an interval 0 <= lo <= hi, got {(lo, hi)!r}")
        for name in ("lead_end", "overlap", "rotation_onset", "rotation_end", "finger_onset"):
            if getattr(self, name)[1] > 1.0:
                raise ConfigError(f"{name} is a phase and must lie in [0, 1]")
        if self.speed_mps[0] <= 0 or self.rot_speed_radps[0] <= 0:
            raise ConfigError("speed_mps and rot_speed_radps must be > 0")
        if self.rotation_onset[1] >= self.rotation_end[0]:
            raise ConfigError("rotation_onset must end before rotation_end starts")
        if not 0.0 <= self.lead_probability <= 1.0:
            raise ConfigError("lead_probability must lie in [0, 1]")
        if any(a not in (0, 1, 2) for a in self.lead_axes):
            raise ConfigError("lead_axes are translational axes 0, 1, 2")
        if len(self.noise_dims) != 6:
            raise ConfigError("noise_dims needs six flags (x, y, z, roll, pitch, yaw)")
        for name in (
            "min_move_s", "speed_variability", "pause_rate", "wander_m", "wander_rad",
            "endpoint_sd_m", "endpoint_sd_rad",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be finite and >= 0, got {v!r}")
        if not (self.v_cap_mps > 0 and self.w_cap_radps > 0):
            raise ConfigError("v_cap_mps and w_cap_radps must be > 0")


@dataclass(frozen=True)
class OperatorSample:
    """What was drawn for one trajectory (phases in [0, 1], times in seconds).

    Attributes:
        target: the state the operator ends at (goal plus endpoint error), unbatched.
        lead: whether the lead-axes strategy was used.
        windows: (5, 2) phase windows of x, y, z, rotation, fingers.
        move_s: movement time without pauses [s].
        pauses: (phase, length [s]) of each pause.
        reaction_s: still time before the movement [s].
        hold_s: still time after the movement [s].
    """

    target: HandState
    lead: bool
    windows: Array
    move_s: float
    pauses: tuple[tuple[float, float], ...]
    reaction_s: float
    hold_s: float


@dataclass(frozen=True)
class OperatorTrajectory:
    """One sampled trajectory: T ticks of the operator's mapped hand.

    Attributes:
        t_s: (T,) tick times from 0 [s], spaced dt.
        states: HandState with position (T, 3), rotation (T, 3, 3), openness (T, F).
        sample: the drawn strategy parameters.
    """

    t_s: Array
    states: HandState
    sample: OperatorSample

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def min_jerk(u: Array) -> Array:
    """Minimum-jerk progress m(u) = 10u^3 - 15u^4 + 6u^5 of u clipped to [0, 1]."""
    u = np.clip(u, 0.0, 1.0)
    return np.asarray(u * u * u * (10.0 + u * (-15.0 + 6.0 * u)))


def sample_trajectory(
    start: HandState,
    goal: HandState,
    dt: float,
    rng: np.random.Generator | int | Sequence[int],
    strategy: OperatorStrategy | None = None,
) -> OperatorTrajectory:
    """Draw one operator trajectory from `start` to (near) `goal`.

    Args:
        start: unbatched start state of the hand (position (3,), rotation (3, 3), openness (F,)).
        goal: unbatched state the operator aims for (their own goal, not the robot's).
        dt: tick [s], > 0.
        rng: a numpy Generator, or a seed (int or sequence of ints) for one.
        strategy: strategy distributions; defaults to OperatorStrategy().

    Returns:
        The trajectory; it starts exactly at `start` and ends holding still at the target.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ContractError(f"dt must be > 0, got {dt!r}")
    if start.position.shape != (3,) or goal.position.shape != (3,):
        raise ContractError("start and goal must be single (unbatched) states")
    if start.n_fingers != goal.n_fingers:
        raise ContractError("start and goal have different finger counts")
    st = strategy or OperatorStrategy()
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    mask = np.asarray(st.noise_dims, dtype=np.float64)

    # Everything random is drawn here, before any length is known, so the draws do not
    # depend on dt or on the speed-cap stretching below.
    u = gen.random(16)
    d_p = gen.standard_normal(3) * st.endpoint_sd_m * mask[:3]
    d_r = gen.standard_normal(3) * st.endpoint_sd_rad * mask[3:]
    speed_knots = gen.standard_normal(_N_KNOTS)
    wander_knots = gen.standard_normal((_N_KNOTS, 6)) * mask
    n_pauses_per_s = st.pause_rate
    pause_draw = gen.random(8)

    def pick(iv: Interval, x: float) -> float:
        return float(iv[0] + (iv[1] - iv[0]) * x)

    p0, pT = start.position, goal.position + d_p
    R0 = start.rotation
    RT = so3_exp(d_r) @ goal.rotation
    g0, gT = start.openness, goal.openness
    target = HandState(pT, RT, gT.copy())
    w_total = so3_log(RT @ R0.T)

    lead = bool(st.lead_axes) and u[0] < st.lead_probability
    windows = np.zeros((5, 2))
    windows[:3] = (0.0, 1.0)
    if lead:
        lead_end = pick(st.lead_end, u[1])
        other_on = max(0.0, lead_end - pick(st.overlap, u[2]))
        for ax in range(3):
            windows[ax] = (0.0, lead_end) if ax in st.lead_axes else (other_on, 1.0)
    windows[3] = (pick(st.rotation_onset, u[3]), pick(st.rotation_end, u[4]))
    windows[4] = (pick(st.finger_onset, u[5]), 1.0)

    d = pT - p0
    path_m = float(np.abs(d).sum() if lead else np.linalg.norm(d))
    angle = float(np.linalg.norm(w_total))
    rot_window = float(windows[3, 1] - windows[3, 0])
    move_s = max(
        path_m / pick(st.speed_mps, u[6]),
        angle / pick(st.rot_speed_radps, u[7]) / max(rot_window, 1e-3),
        st.min_move_s,
    )
    reaction_s = pick(st.reaction_s, u[8])
    hold_s = pick(st.hold_s, u[9])
    # Poisson number of pauses from the expected count over the (first) movement time.
    n_pauses = int(min(4, _poisson_from_uniform(n_pauses_per_s * move_s, u[10])))
    pauses = tuple(
        (0.1 + 0.8 * float(pause_draw[2 * j]), pick(st.pause_s, float(pause_draw[2 * j + 1])))
        for j in range(n_pauses)
    )

    # Speed multiplier and wander as smooth functions of phase.
    tau_grid = np.linspace(0.0, 1.0, _PHASE_GRID)
    log_m = st.speed_variability * _smooth(speed_knots[:, None], tau_grid)[:, 0]
    inv_rate = np.exp(-log_m)  # time spent per unit phase, up to scale
    cum = np.concatenate(
        [[0.0], np.cumsum(0.5 * (inv_rate[1:] + inv_rate[:-1]) * np.diff(tau_grid))]
    )
    cum /= cum[-1]
    envelope = np.sin(np.pi * tau_grid)[:, None]
    wander = _smooth(wander_knots, tau_grid) * envelope
    wander[:, :3] *= st.wander_m
    wander[:, 3:] *= st.wander_rad

    for _ in range(6):
        t_of_tau, tau_of_t = _time_map(cum, tau_grid, move_s, pauses, reaction_s)
        total_s = t_of_tau[-1] + hold_s
        n_ticks = int(np.ceil(total_s / dt)) + 1
        t = np.arange(n_ticks) * dt
        tau = np.interp(t, t_of_tau, tau_of_t)
        pos, rotvec, wander_t = _path(tau, tau_grid, windows, p0, d, w_total, wander)
        v_peak = float(np.max(np.linalg.norm(np.diff(pos, axis=0), axis=-1), initial=0.0)) / dt
        w_peak = float(np.max(np.linalg.norm(np.diff(rotvec, axis=0), axis=-1), initial=0.0)) / dt
        ratio = max(v_peak / st.v_cap_mps, w_peak / st.w_cap_radps)
        if ratio <= 1.0:
            break
        move_s *= ratio * 1.02

    # The rotation path is exp(w_wander) exp(s_R w_total) R_0; fingers follow their window.
    rot = so3_exp(wander_t[:, 3:]) @ so3_exp(rotvec - wander_t[:, 3:]) @ R0
    opn = g0 + _progress(tau, windows[4])[:, None] * (gT - g0)
    states = HandState(pos, rot, opn)
    sample = OperatorSample(target, lead, windows, float(move_s), pauses, reaction_s, hold_s)
    return OperatorTrajectory(np.asarray(t, dtype=np.float64), states, sample)


def stack(trajectories: Sequence[OperatorTrajectory]) -> tuple[HandState, NDArray[np.int64]]:
    """Stack trajectories into one batch, padding each with its last state (holding still).

    Returns:
        HandState with position (N, T, 3), rotation (N, T, 3, 3), openness (N, T, F) where T
        is the longest length, and the lengths (N,).
    """
    if not trajectories:
        raise ContractError("no trajectories to stack")
    lengths = np.array([len(tr) for tr in trajectories], dtype=np.int64)
    T = int(lengths.max())

    def pad(a: Array) -> Array:
        extra = T - a.shape[0]
        if extra == 0:
            return a
        return np.concatenate([a, np.repeat(a[-1:], extra, axis=0)], axis=0)

    pos = np.stack([pad(tr.states.position) for tr in trajectories])
    rot = np.stack([pad(tr.states.rotation) for tr in trajectories])
    opn = np.stack([pad(tr.states.openness) for tr in trajectories])
    return HandState(pos, rot, opn), lengths


def _progress(tau: Array, window: Array) -> Array:
    on, off = float(window[0]), float(window[1])
    return min_jerk((tau - on) / max(off - on, 1e-9))


def _path(
    tau: Array,
    tau_grid: Array,
    windows: Array,
    p0: Array,
    d: Array,
    w_total: Array,
    wander_grid: Array,
) -> tuple[Array, Array, Array]:
    """Positions (n, 3), rotation vectors relative to R_0 (n, 3) and the wander (n, 6).

    The rotation vector s_R w_total + w_wander is exact for a planar (one-axis) rotation and
    a first-order approximation otherwise; it is used for the speed cap only.
    """
    wander = np.stack([np.interp(tau, tau_grid, wander_grid[:, j]) for j in range(6)], -1)
    s = np.stack([_progress(tau, windows[k]) for k in range(3)], -1)
    pos = p0 + s * d + wander[:, :3]
    rotvec = _progress(tau, windows[3])[:, None] * w_total + wander[:, 3:]
    return pos, rotvec, wander


def _time_map(
    cum: Array,
    tau_grid: Array,
    move_s: float,
    pauses: tuple[tuple[float, float], ...],
    reaction_s: float,
) -> tuple[Array, Array]:
    """Increasing times t(tau) with the pauses as flat steps in tau, and the matching tau."""
    t = reaction_s + move_s * cum
    tau = tau_grid
    for phase, length in sorted(pauses):
        k = int(np.searchsorted(tau, phase))
        t_at = float(np.interp(phase, tau, t))
        t = np.concatenate([t[:k], [t_at, t_at + length], t[k:] + length])
        tau = np.concatenate([tau[:k], [phase, phase], tau[k:]])
    t = np.concatenate([[0.0], t])
    tau = np.concatenate([[0.0], tau])
    return t, tau


def _smooth(knots: Array, tau: Array) -> Array:
    """Cubic (Catmull-Rom) interpolation of knots spread evenly over [0, 1], (K, C) -> (n, C)."""
    K = knots.shape[0]
    x = tau * (K - 1)
    i = np.clip(np.floor(x).astype(int), 0, K - 2)
    f = (x - i)[:, None]
    P = np.concatenate([knots[:1], knots, knots[-1:]], axis=0)
    p0, p1, p2, p3 = P[i], P[i + 1], P[i + 2], P[i + 3]
    return np.asarray(
        0.5
        * (
            2.0 * p1
            + (-p0 + p2) * f
            + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * f * f
            + (-p0 + 3.0 * p1 - 3.0 * p2 + p3) * f * f * f
        )
    )


def _poisson_from_uniform(lam: float, x: float) -> int:
    """Inverse-CDF Poisson draw from one uniform (keeps the number of draws fixed)."""
    k, p = 0, np.exp(-lam)
    cdf = p
    while x > cdf and k < 50:
        k += 1
        p *= lam / k
        cdf += p
    return k
