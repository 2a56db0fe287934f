"""The paper's simulation study (Section IV-A/B) as a pure computation: no I/O, no clock.

World (docs/METHOD.md, docs/sim.md): a planar task with three DOF, x, y [m] and heading
[rad], embedded in the 6 + F arbitration with z = 0, roll = pitch = 0 and F = 0 fingers. The
hand starts at `start` and reaches for an object's handle at `handle_xy_m`, whose grasp normal
is `handle_normal_rad`. For trajectory n (seeded by (seed, n) alone, so results do not
depend on batching or workers):

    operator goal    handle position, heading = normal (`aligned` operator) or
                     normal - offset, offset ~ U(side_offset_rad) (`side` operator: agrees on
                     position, prefers to grasp the handle from the side)
    operator         app.operator.open_loop.sample_trajectory (open loop, y before x, ...)
    robot goal       handle position + N(0, goal_sigma_m^2 I_2), heading = normal +
                     N(0, goal_heading_sigma_rad^2)
    robot            X_{k+1} = integrate(X_k, U_out_k, dt), eq (1)-(2), U_human_k from the
                     hand's motion H_k -> H_{k+1}, under each mode (S, DS, manual,
                     autonomous) with the same operator sample and goal noise (paired)

The trial lasts as long as the operator's trajectory (L ticks). Success: the robot's final
pose is within `success_radius_m` of the handle position and within `success_heading_rad` of
the normal. Completion time: the time from which the robot stays in that region to the end
(its settling time), or the whole trial, (L - 1) dt, on failure.

Per trajectory the metrics of Section IV-D (dsteleop.arbitration.metrics) are taken over the
actions of the trial: cosine distance (mean per action) and ratio of agreement of U_human vs
U_out, in the arbitration's units (m/s, rad/s).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.operator.open_loop import (
    OperatorStrategy,
    OperatorTrajectory,
    sample_trajectory,
    stack,
)
from dsteleop.app.session.trace import Trace
from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    ArbitrationStep,
    HandState,
    Mode,
    dim_names,
    make_arbiter,
    metrics,
    so3_exp,
)
from dsteleop.arbitration.se3 import stack as stack_states
from dsteleop.errors import ConfigError
from dsteleop.robot.task import Phase

Array = NDArray[np.float64]
OperatorKind = Literal["side", "aligned"]
OPERATORS: tuple[str, ...] = ("side", "aligned")
ALL_MODES: tuple[Mode, ...] = (Mode.S, Mode.DS, Mode.MANUAL, Mode.AUTONOMOUS)
SCHEMA = "dsteleop.sim_summary/1"
HIST_BINS = 16
PATH_STRIDE = 3  # keep every 3rd tick of the example paths (Fig. 5b)
PHASE_EDGES = np.linspace(0.0, 1.0, 11)  # deciles of each trial for the by-phase metrics
Y_ONLY_MPS = 0.02  # operator speed along y above which a y-only action counts [m/s]


def planar_strategy(arb: ArbitrationConfig) -> OperatorStrategy:
    """The default operator strategy of the planar study: noise only in x, y and heading,
    speeds capped just under the robot's limits."""
    return OperatorStrategy(
        noise_dims=(True, True, False, False, False, True),
        v_cap_mps=0.95 * arb.v_max_mps,
        w_cap_radps=0.95 * arb.w_max_radps,
    )


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a run of the study (recorded in summary.json).

    Attributes:
        trajectories: number of operator trajectories, >= 1.
        seed: master seed; trajectory n uses the generator seeded with (seed, n).
        operator: `side` (the paper's scenario) or `aligned` (agrees on every dimension).
        modes: arbitration modes, each run on every trajectory.
        dt_s: tick [s].
        start_xy_m: start position [m]; start heading `start_heading_rad` [rad].
        handle_xy_m: handle position [m].
        handle_normal_rad: heading of the grasp normal [rad].
        success_radius_m: R of the success test [m].
        success_heading_rad: delta of the success test [rad].
        goal_sigma_m: standard deviation of the robot's goal position per axis [m].
        goal_heading_sigma_rad: standard deviation of the robot's goal heading [rad].
        side_offset_rad: interval of the side operator's heading offset from the normal [rad].
        example: index of the trajectory drawn in the per-trajectory figures; None picks
            the first one that moves y before x.
        max_paths: trajectories whose paths are kept for the distribution figure.
        arbitration: arbitration hyper-parameters.
        strategy: operator strategy; None gives planar_strategy(arbitration).
    """

    trajectories: int = 1000
    seed: int = 0
    operator: OperatorKind = "side"
    modes: tuple[Mode, ...] = ALL_MODES
    dt_s: float = 1.0 / 30.0
    start_xy_m: tuple[float, float] = (0.0, 0.0)
    start_heading_rad: float = 0.0
    handle_xy_m: tuple[float, float] = (0.30, 0.40)
    handle_normal_rad: float = math.pi / 4
    success_radius_m: float = 0.03
    success_heading_rad: float = 0.35
    goal_sigma_m: float = 0.02
    goal_heading_sigma_rad: float = 0.0
    side_offset_rad: tuple[float, float] = (0.15, 0.30)
    example: int | None = None
    max_paths: int = 200
    arbitration: ArbitrationConfig = field(default_factory=ArbitrationConfig)
    strategy: OperatorStrategy | None = None

    def __post_init__(self) -> None:
        if isinstance(self.trajectories, bool) or not isinstance(self.trajectories, int):
            raise ConfigError(f"trajectories must be an integer, got {self.trajectories!r}")
        if self.trajectories < 1:
            raise ConfigError(f"trajectories must be >= 1, got {self.trajectories}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        if self.operator not in OPERATORS:
            raise ConfigError(f"unknown operator {self.operator!r} (choose from side, aligned)")
        if not self.modes or len(set(self.modes)) != len(self.modes):
            raise ConfigError("modes must be a non-empty list without repeats")
        for name in ("dt_s", "success_radius_m", "success_heading_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be finite and > 0, got {v!r}")
        for name in ("goal_sigma_m", "goal_heading_sigma_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be finite and >= 0, got {v!r}")
        lo, hi = self.side_offset_rad
        if not 0 <= lo <= hi < math.pi:
            raise ConfigError(f"side_offset_rad must satisfy 0 <= lo <= hi < pi, got {(lo, hi)}")
        if self.example is not None and not 0 <= self.example < self.trajectories:
            raise ConfigError(
                f"example must be in [0, {self.trajectories - 1}], got {self.example}"
            )
        if self.max_paths < 0:
            raise ConfigError(f"max_paths must be >= 0, got {self.max_paths}")

    @property
    def operator_strategy(self) -> OperatorStrategy:
        return self.strategy or planar_strategy(self.arbitration)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (modes by name, nested configs as dicts)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "modes":
                v = [m.value for m in v]
            elif f.name == "arbitration":
                v = v.to_dict()
            elif f.name == "strategy":
                v = _jsonable(dataclasses.asdict(self.operator_strategy))
            elif isinstance(v, tuple):
                v = list(v)
            out[f.name] = v
        return out


def planar_state(x: Array, y: Array, heading: Array) -> HandState:
    """HandState(s) of planar poses: z = 0, roll = pitch = 0, no fingers; any batch shape."""
    x, y, heading = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (x, y, heading)))
    pos = np.stack([x, y, np.zeros_like(x)], -1)
    rv = np.stack([np.zeros_like(x), np.zeros_like(x), heading], -1)
    return HandState(pos, so3_exp(rv), np.zeros((*x.shape, 0)))


def heading_of(R: Array) -> Array:
    """Heading (yaw about z) [rad] of rotation matrices (..., 3, 3), in (-pi, pi]."""
    return np.asarray(np.arctan2(R[..., 1, 0], R[..., 0, 0]))


def wrap(a: Array) -> Array:
    """Angles wrapped to (-pi, pi]."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(a), 2.0 * np.pi))


def in_success_region(
    xy: Array,
    heading: Array,
    handle_xy: Array | Sequence[float],
    normal: float,
    R: float,
    delta: float,
) -> NDArray[np.bool_]:
    """The success test: within R [m] of the handle and within delta [rad] of its normal.

    Args:
        xy: (..., 2) positions [m].
        heading: (...) headings [rad].
        handle_xy: (2,) handle position [m].
        normal: heading of the grasp normal [rad].
        R: radius [m].
        delta: heading tolerance [rad].
    """
    d = np.linalg.norm(np.asarray(xy) - np.asarray(handle_xy), axis=-1)
    return np.asarray((d <= R) & (np.abs(wrap(np.asarray(heading) - normal)) <= delta))


@dataclass(frozen=True)
class Trial:
    """The random part of one trajectory: the operator's hand and the robot's goal.

    Attributes:
        index: trajectory index n (seeded by (seed, n)).
        operator: the operator's sampled trajectory (hand states (T, ...), tick times).
        robot_goal: (3,) x [m], y [m], heading [rad] the robot aims for.
        operator_goal: (3,) x, y, heading the operator aims for.
    """

    index: int
    operator: OperatorTrajectory
    robot_goal: Array
    operator_goal: Array

    @property
    def hand(self) -> HandState:
        return self.operator.states

    @property
    def t_s(self) -> Array:
        return self.operator.t_s

    @property
    def lead(self) -> bool:
        return self.operator.sample.lead


def sample_trial(cfg: SimConfig, index: int) -> Trial:
    """Trajectory `index`: seeded by (seed, index) only."""
    rng = np.random.default_rng([cfg.seed, index])
    hx, hy = cfg.handle_xy_m
    noise = rng.standard_normal(3)
    robot_goal = np.array(
        [
            hx + cfg.goal_sigma_m * noise[0],
            hy + cfg.goal_sigma_m * noise[1],
            cfg.handle_normal_rad + cfg.goal_heading_sigma_rad * noise[2],
        ]
    )
    offset = float(rng.uniform(*cfg.side_offset_rad)) if cfg.operator == "side" else 0.0
    op_goal = np.array([hx, hy, cfg.handle_normal_rad - offset])
    start = planar_state(*cfg.start_xy_m, cfg.start_heading_rad)  # type: ignore[arg-type]
    goal = planar_state(*op_goal)
    tr = sample_trajectory(start, goal, cfg.dt_s, rng, cfg.operator_strategy)
    return Trial(index, tr, robot_goal, op_goal)


@dataclass(frozen=True)
class ModeResult:
    """Per-trajectory results of one mode over a set of trajectories (arrays (N,))."""

    success: NDArray[np.bool_]
    time_s: Array
    cosine_mean: Array
    cosine_sum: Array
    agreement: Array
    n_actions: NDArray[np.int64]
    final: Array  # (N, 3) final x, y, heading of the robot
    hist: NDArray[np.int64]  # 3-D histogram of the robot's (x, y, heading) over all ticks
    paths: Array  # (P, T', 3) robot (x, y, heading) of the first trajectories, padded with nan
    phase_cos: Array  # (N, 2, bins) sum and count of the cosine distance per phase bin
    phase_agree: Array  # (N, 2, bins) agreements and actions per phase bin
    y_only: Array  # (N, 3) sum |U_out_x|, sum |U_out_y|, actions while the operator moves y only


@dataclass(frozen=True)
class ChunkResult:
    """Results of a contiguous set of trajectories under every mode."""

    indices: NDArray[np.int64]
    lengths: NDArray[np.int64]
    lead: NDArray[np.bool_]
    operator_hist: NDArray[np.int64]
    operator_paths: Array
    modes: dict[str, ModeResult]


def first_lead_index(cfg: SimConfig) -> int:
    """The first trajectory that moves y before x (0 if none): the default example."""
    for i in range(cfg.trajectories):
        if sample_trial(cfg, i).lead:
            return i
    return 0


def hist_ranges(cfg: SimConfig) -> Array:
    """(3, 2) ranges of the trajectory histograms: the start-handle box with a margin."""
    sx, sy = cfg.start_xy_m
    hx, hy = cfg.handle_xy_m
    m = 0.1
    h = [
        cfg.start_heading_rad,
        cfg.handle_normal_rad,
        cfg.handle_normal_rad - cfg.side_offset_rad[1],
    ]
    return np.array(
        [
            [min(sx, hx) - m, max(sx, hx) + m],
            [min(sy, hy) - m, max(sy, hy) + m],
            [min(h) - 0.5, max(h) + 0.5],
        ]
    )


def run_chunk(
    cfg: SimConfig, indices: Sequence[int], on_progress: Callable[[int], None] | None = None
) -> ChunkResult:
    """Sample trajectories `indices` and run them under every mode of `cfg`, batched.

    Args:
        cfg: the study.
        indices: trajectory indices.
        on_progress: called with a count of trajectory-modes done (for a progress bar).
    """
    idx = np.asarray(indices, dtype=np.int64)
    trials = [sample_trial(cfg, int(i)) for i in idx]
    hands, lengths = stack([t.operator for t in trials])
    ranges = hist_ranges(cfg)
    pose_h = np.concatenate(
        [hands.position[..., :2], heading_of(hands.rotation)[..., None]], axis=-1
    )
    valid = np.arange(pose_h.shape[1])[None, :] < lengths[:, None]
    n_paths = int(np.clip(cfg.max_paths - idx[0], 0, len(idx))) if len(idx) else 0
    op_hist = metrics.trajectory_histogram(pose_h[valid], HIST_BINS, ranges)
    op_paths = _paths(pose_h[:n_paths], lengths[:n_paths])
    goals = np.stack([t.robot_goal for t in trials])
    hands_tm = _time_major(hands)
    modes: dict[str, ModeResult] = {}
    for mode in cfg.modes:
        modes[mode.value] = _run_mode(cfg, mode, hands_tm, lengths, goals, ranges, n_paths)
        if on_progress is not None:
            on_progress(len(idx))
    lead = np.array([t.lead for t in trials], dtype=bool)
    return ChunkResult(idx, lengths, lead, op_hist, op_paths, modes)


def trace(cfg: SimConfig, index: int, mode: Mode) -> Trace:
    """Run one trajectory under one mode and keep every tick: T = L - 1 ticks of a trial of
    L states (tick k takes the robot from state k to state k + 1, at time t_{k+1})."""
    trial = sample_trial(cfg, index)
    hands, lengths = stack([trial.operator])
    goals = trial.robot_goal[None]
    steps: list[ArbitrationStep] = []
    robot = _simulate(cfg, mode, _time_major(hands), lengths, goals, steps)
    L = int(lengths[0])
    first = steps[: L - 1]
    step = ArbitrationStep(
        **{k: np.stack([getattr(s, k)[0] for s in first]) for k in STEP_ARRAYS},
        X_next=stack_states([s.X_next.take(0) for s in first]),
    )
    v_max = cfg.arbitration.v_max(0)
    return Trace(
        name=f"trajectory {index}",
        mode=mode,
        dims=dim_names(0),
        t_s=trial.t_s[1:L],
        arbitrated=np.ones(L - 1, dtype=bool),
        step=step,
        p_human=trial.hand.position[1:L],
        p_robot=np.concatenate([robot[0, 1:L, :2], np.zeros((L - 1, 1))], -1),
        p_goal=np.tile([*trial.robot_goal[:2], 0.0], (L - 1, 1)),
        phases=(Phase.PICK,) * (L - 1),
        outcome=None,
        time_s=float(trial.t_s[L - 1]),
        v_max=v_max,
    )


def _simulate(
    cfg: SimConfig,
    mode: Mode,
    hands_tm: HandState,
    lengths: NDArray[np.int64],
    goals: Array,
    record: list[ArbitrationStep] | None = None,
    on_step: Callable[[int, NDArray[np.int64], Array, Array], None] | None = None,
) -> Array:
    """Step the batch through time; returns the robot's (x, y, heading), (N, T, 3), nan past
    the end of each trial.

    Rows whose trial has ended are dropped from the batch every few ticks (the arbitration is
    row-wise, so this changes no result, only the work). on_step(k, rows, U_human, U_out) is
    called after tick k with the original indices of the rows whose trial includes tick k.
    `hands_tm` is time-major: position (T, N, 3), rotation (T, N, 3, 3), openness (T, N, F).
    """
    T, N = hands_tm.position.shape[:2]
    arb = make_arbiter(mode, cfg.arbitration)
    state = arb.initial_state(6, batch=(N,))
    X0 = planar_state(
        np.full(N, cfg.start_xy_m[0]),
        np.full(N, cfg.start_xy_m[1]),
        np.full(N, cfg.start_heading_rad),
    )
    G = planar_state(goals[:, 0], goals[:, 1], goals[:, 2])
    # Time-major, so that each tick reads contiguous rows; `base` is the first tick the
    # arrays hold (compaction keeps only the future).
    pos, rot, opn = hands_tm.position, hands_tm.rotation, hands_tm.openness
    base = 0
    rows = np.arange(N)
    X, Xp, X0r = X0, X0, X0
    H0 = HandState(pos[0], rot[0], opn[0])
    xy = np.full((T, N, 2), np.nan)
    cs = np.full((T, N, 2), np.nan)  # cos, sin of the heading
    xy[0], cs[0] = X.position[:, :2], X.rotation[:, :2, 0]
    T_run = int(lengths.max())
    for k in range(T_run - 1):
        if k % 16 == 0 and k > 0:
            keep = lengths[rows] > k + 1
            if keep.sum() < 0.9 * rows.size:
                rows = rows[keep]
                state = state.select(keep)
                X, Xp, X0r, H0, G = (h.take(keep) for h in (X, Xp, X0r, H0, G))
                pos, rot, opn = (a[k - base :, keep] for a in (pos, rot, opn))
                base = k
        i = k - base
        H = HandState(pos[i + 1], rot[i + 1], opn[i + 1])
        Hp = HandState(pos[i], rot[i], opn[i])
        inp = ArbitrationInput(H, Hp, H0, X, Xp, X0r, G, cfg.dt_s)
        state, step = arb.step(state, inp)
        Xp, X = X, step.X_next
        xy[k + 1, rows] = X.position[:, :2]
        cs[k + 1, rows] = X.rotation[:, :2, 0]
        if record is not None:
            record.append(step)
        if on_step is not None:
            act = lengths[rows] > k + 1
            if act.all():
                on_step(k, rows, step.U_human, step.U_out)
            else:
                on_step(k, rows[act], step.U_human[act], step.U_out[act])
    out = np.concatenate([xy, np.arctan2(cs[..., 1], cs[..., 0])[..., None]], -1)
    out = np.ascontiguousarray(np.swapaxes(out, 0, 1))
    past = np.arange(T)[None, :] >= lengths[:, None]
    out[past] = np.nan
    return out


def _time_major(hands: HandState) -> HandState:
    """(N, T, ...) -> contiguous (T, N, ...) copies."""
    return HandState(
        *(
            np.ascontiguousarray(np.swapaxes(a, 0, 1))
            for a in (hands.position, hands.rotation, hands.openness)
        )
    )


def _run_mode(
    cfg: SimConfig,
    mode: Mode,
    hands_tm: HandState,
    lengths: NDArray[np.int64],
    goals: Array,
    ranges: Array,
    n_paths: int,
) -> ModeResult:
    T, N = hands_tm.position.shape[:2]
    # Every action of every trial, time-major (one contiguous write per tick); the metrics
    # are computed afterwards over whole arrays with dsteleop.arbitration.metrics.
    U_h_all = np.zeros((T - 1, N, 6))
    U_out_all = np.zeros((T - 1, N, 6))
    acted = np.zeros((T - 1, N), dtype=bool)

    def on_step(k: int, rows: NDArray[np.int64], U_h: Array, U_out: Array) -> None:
        U_h_all[k, rows] = U_h
        U_out_all[k, rows] = U_out
        acted[k, rows] = True

    poses = _simulate(cfg, mode, hands_tm, lengths, goals, on_step=on_step)
    U_h_all, U_out_all = np.swapaxes(U_h_all, 0, 1), np.swapaxes(U_out_all, 0, 1)  # (N, T-1, 6)
    acted = acted.T
    cos = metrics.cosine_distance(U_h_all, U_out_all, acted)
    ag = metrics.agreement(U_h_all, U_out_all, acted)
    # By phase of the trial: tick k of a trial of L ticks is at phase k / (L - 1).
    n_bins = len(PHASE_EDGES) - 1
    k = np.arange(T - 1)[None, :]
    phase = k / (lengths[:, None] - 1)
    b = np.clip(np.searchsorted(PHASE_EDGES, phase, side="right") - 1, 0, n_bins - 1)
    c = metrics.action_cosine_distance(U_h_all, U_out_all)
    counted = acted & ~np.isnan(c)
    moving = acted & (np.linalg.norm(U_h_all, axis=-1) > 1e-9)
    agrees = moving & (np.einsum("ntd,ntd->nt", U_h_all, U_out_all) > 0.0)
    # Per trajectory (N, 2, bins), so pooled sums do not depend on how rows were chunked.
    cos_bins = _bin_sum(b, np.where(counted, c, 0.0), n_bins)
    ph_cos = np.stack([cos_bins, _bin_sum(b, counted, n_bins)], 1)
    ph_ag = np.stack([_bin_sum(b, agrees, n_bins), _bin_sum(b, moving, n_bins)], 1)
    # Operator moving along y only (|v_x| < 0.1 |v_y|, |v_y| > 0.02 m/s): how much x does the
    # output add (the paper's Fig. 5 narrative)?
    vx, vy = np.abs(U_h_all[..., 0]), np.abs(U_h_all[..., 1])
    y_only = acted & (vy > Y_ONLY_MPS) & (vx < 0.1 * vy)
    cross = np.stack(
        [
            np.where(y_only, np.abs(U_out_all[..., 0]), 0.0).sum(1),
            np.where(y_only, np.abs(U_out_all[..., 1]), 0.0).sum(1),
            y_only.sum(1).astype(np.float64),
        ],
        -1,
    )
    T = poses.shape[1]
    valid = np.arange(T)[None, :] < lengths[:, None]
    inside = in_success_region(
        poses[..., :2],
        poses[..., 2],
        cfg.handle_xy_m,
        cfg.handle_normal_rad,
        cfg.success_radius_m,
        cfg.success_heading_rad,
    )
    rows = np.arange(N)
    last = lengths - 1
    success = inside[rows, last]
    # Settling time: the first tick after the last one outside the region.
    outside = valid & ~inside
    last_out = np.where(outside.any(1), T - 1 - np.argmax(outside[:, ::-1], axis=1), -1)
    settle = (last_out + 1) * cfg.dt_s
    time_s = np.where(success, np.maximum(settle, cfg.dt_s), last * cfg.dt_s)
    return ModeResult(
        success=success,
        time_s=time_s,
        cosine_mean=cos.mean,
        cosine_sum=cos.total,
        agreement=ag.ratio,
        n_actions=cos.n_actions,
        final=poses[rows, last],
        hist=metrics.trajectory_histogram(poses[valid], HIST_BINS, ranges),
        paths=_paths(poses[:n_paths], lengths[:n_paths]),
        phase_cos=ph_cos,
        phase_agree=ph_ag,
        y_only=cross,
    )


def _bin_sum(bins: NDArray[np.intp], weights: NDArray[np.float64 | np.bool_], n_bins: int) -> Array:
    """Per row, the sums of `weights` (N, T) over the bins (N, T) -> (N, n_bins)."""
    N = bins.shape[0]
    flat = (np.arange(N)[:, None] * n_bins + bins).ravel()
    w = np.asarray(weights, dtype=np.float64).ravel()
    return np.asarray(np.bincount(flat, w, N * n_bins), dtype=np.float64).reshape(N, n_bins)


def _paths(poses: Array, lengths: NDArray[np.int64]) -> Array:
    p = poses[:, ::PATH_STRIDE].copy()
    keep = np.arange(p.shape[1])[None, :] * PATH_STRIDE < lengths[:, None]
    p[~keep] = np.nan
    return p


# --- summary --------------------------------------------------------------------------------


@dataclass(frozen=True)
class StudyResult:
    """All trajectories of a study, merged from chunks in index order."""

    config: SimConfig
    lengths: NDArray[np.int64]
    lead: NDArray[np.bool_]
    operator_hist: NDArray[np.int64]
    operator_paths: Array
    modes: dict[str, ModeResult]


def merge(cfg: SimConfig, chunks: Sequence[ChunkResult]) -> StudyResult:
    """Concatenate chunk results in trajectory order (chunks may arrive in any order)."""
    ordered = sorted(chunks, key=lambda c: int(c.indices[0]))
    idx = np.concatenate([c.indices for c in ordered])
    if not np.array_equal(idx, np.arange(cfg.trajectories)):
        raise ValueError("chunks do not cover the trajectories exactly once")

    def cat(arrs: list[Array]) -> Array:
        return np.concatenate(arrs) if arrs else np.zeros(0)

    def cat_paths(arrs: list[Array]) -> Array:
        arrs = [a for a in arrs if a.shape[0] > 0]
        if not arrs:
            return np.zeros((0, 1, 3))
        T = max(a.shape[1] for a in arrs)
        return np.concatenate(
            [np.pad(a, ((0, 0), (0, T - a.shape[1]), (0, 0)), constant_values=np.nan) for a in arrs]
        )

    modes = {}
    for m in cfg.modes:
        parts = [c.modes[m.value] for c in ordered]
        modes[m.value] = ModeResult(
            success=np.concatenate([p.success for p in parts]),
            time_s=cat([p.time_s for p in parts]),
            cosine_mean=cat([p.cosine_mean for p in parts]),
            cosine_sum=cat([p.cosine_sum for p in parts]),
            agreement=cat([p.agreement for p in parts]),
            n_actions=np.concatenate([p.n_actions for p in parts]),
            final=np.concatenate([p.final for p in parts]),
            hist=np.sum([p.hist for p in parts], axis=0),
            paths=cat_paths([p.paths for p in parts]),
            phase_cos=np.concatenate([p.phase_cos for p in parts]),
            phase_agree=np.concatenate([p.phase_agree for p in parts]),
            y_only=np.concatenate([p.y_only for p in parts]),
        )
    return StudyResult(
        config=cfg,
        lengths=np.concatenate([c.lengths for c in ordered]),
        lead=np.concatenate([c.lead for c in ordered]),
        operator_hist=np.sum([c.operator_hist for c in ordered], axis=0),
        operator_paths=cat_paths([c.operator_paths for c in ordered]),
        modes=modes,
    )


def summarise(res: StudyResult) -> dict[str, Any]:
    """The summary.json object: per mode metrics, S vs DS tests, divergences, config."""
    cfg = res.config
    modes: dict[str, Any] = {}
    for name, r in res.modes.items():
        sr = metrics.success_rate(int(r.success.sum()), int(r.success.size))
        gm = metrics.geometric_mean(r.time_s)
        modes[name] = {
            "n": int(r.success.size),
            "success_rate": {
                "estimate": sr.laplace,
                "ci95": [sr.ci_low, sr.ci_high],
                "successes": sr.successes,
                "n": sr.n,
            },
            "time_s": {"geometric_mean": gm.mean, "ci95": [gm.ci_low, gm.ci_high]},
            "cosine_distance": {
                **_mean_ci(r.cosine_mean),
                "mean_sum_per_trajectory": float(r.cosine_sum.mean()),
                "actions": int(r.n_actions.sum()),
            },
            "agreement": _mean_ci(r.agreement),
            "by_phase": {
                "edges": PHASE_EDGES.tolist(),
                "cosine_distance": _ratio(*r.phase_cos.sum(0)),
                "agreement": _ratio(*r.phase_agree.sum(0)),
            },
            "x_per_y_while_operator_moves_y_only": {
                "pooled": _safe_ratio(r.y_only[:, 0].sum(), r.y_only[:, 1].sum()),
                **_mean_ci(x_per_y(r)),
            },
        }
    out: dict[str, Any] = {
        "schema": SCHEMA,
        "seed": cfg.seed,
        "trajectories": cfg.trajectories,
        "modes": modes,
        "tests": {},
        "divergence": _divergences(res),
        "operator": {
            "kind": cfg.operator,
            "lead_share": float(res.lead.mean()),
            "trial_s": _describe(res.lengths * cfg.dt_s),
        },
        "config": cfg.to_dict(),
    }
    if "S" in res.modes and "DS" in res.modes:
        out["tests"]["S_vs_DS"] = compare(res.modes["S"], res.modes["DS"])
    return out


def compare(a: ModeResult, b: ModeResult) -> dict[str, Any]:
    """Tests between two modes on the same trajectories (a minus b in the statistics)."""
    chi = metrics.n1_chi_squared(
        int(a.success.sum()), a.success.size, int(b.success.sum()), b.success.size
    )

    def both(x: Array, y: Array) -> dict[str, Any]:
        ok = np.isfinite(x) & np.isfinite(y)
        return {
            "two_sample_t": dataclasses.asdict(metrics.t_test(x[ok], y[ok])),
            "paired_t": dataclasses.asdict(metrics.paired_t_test(x[ok], y[ok])),
        }

    return {
        "statistics_are": "first minus second mode",
        "success_n1_chi2": dataclasses.asdict(chi),
        "log_time": {
            "two_sample_t": dataclasses.asdict(metrics.log_t_test(a.time_s, b.time_s)),
            "paired_t": dataclasses.asdict(
                metrics.paired_t_test(np.log(a.time_s), np.log(b.time_s))
            ),
        },
        "cosine_distance": both(a.cosine_mean, b.cosine_mean),
        "agreement": both(a.agreement, b.agreement),
        "x_per_y_while_operator_moves_y_only": both(x_per_y(a), x_per_y(b)),
    }


def x_per_y(r: ModeResult) -> Array:
    """Per trajectory: sum |U_out_x| / sum |U_out_y| over the actions where the operator moves
    along y only (nan without such actions) - how much x the output adds (paper Fig. 5)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(
            r.y_only[:, 1] > 0, r.y_only[:, 0] / np.maximum(r.y_only[:, 1], 1e-300), np.nan
        )


def _safe_ratio(a: float, b: float) -> float | None:
    return float(a / b) if b > 0 else None


def _divergences(res: StudyResult) -> dict[str, float]:
    hists = {"operator": res.operator_hist, **{k: v.hist for k, v in res.modes.items()}}
    names = list(hists)
    out = {}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if hists[a].sum() > 0 and hists[b].sum() > 0:
                out[f"{a}~{b}"] = metrics.js_divergence(hists[a], hists[b])
    return out


def _ratio(num: Array, den: Array) -> list[float | None]:
    return [float(a / b) if b > 0 else None for a, b in zip(num, den)]


def _mean_ci(x: Array) -> dict[str, Any]:
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return {"mean": None, "ci95": [None, None], "n": 0}
    m = float(x.mean())
    if n < 2:
        return {"mean": m, "ci95": [m, m], "n": n}
    half = metrics.t_quantile(0.975, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
    return {"mean": m, "ci95": [m - half, m + half], "n": n}


def _describe(x: Array) -> dict[str, float]:
    return {
        "mean": float(np.mean(x)),
        "min": float(np.min(x)),
        "median": float(np.median(x)),
        "max": float(np.max(x)),
    }


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (tuple, list)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v
