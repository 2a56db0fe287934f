"""The paper's simulation study (Section IV-A/B) as a pure computation: no I/O, no clock.

World (docs/METHOD.md, docs/sim.md): a planar task with three DOF, x, y [m] and heading
[rad], embedded in the 6 + F arbitration with z = 0, roll = pitch = 0 and F = 0 fingers. The
hand starts where the robot starts and reaches for an object's handle at `handle_xy_m`, whose
grasp normal is `handle_normal_rad`. For trajectory n (seeded by (seed, n) alone, so results
do not depend on batching or workers):

    robot goal       handle position + N(0, world.goal_sigma_m^2 I_2), heading = normal +
                     N(0, goal_heading_sigma_rad^2) (the same draws for every operator kind;
                     each run of a closed-loop person its own draws)
    robot            X_{k+1} = integrate(X_k, U_out_k, dt), eq (1)-(2), U_human_k from the
                     hand's motion H_k -> H_{k+1}, under each mode (S, DS, manual,
                     autonomous) with the same operator and goal noise (paired)

Operators:

    closed-loop      (the default) `app.operator.closed_loop`, in the world `cfg.world`
                     (docs/operator.md): watches the robot through the link's delay and one
                     camera, and steers it to the TRUE handle, with its own preferred grasp
                     heading (normal - U(side_offset_rad)), y first with probability 0.8,
                     the heading turning only near the handle, settling for the task's goal
                     and tolerance once the robot resists it; the arbitration receives its
                     hand world.delay_s late. A run ends `world.delay_s + grasp_s` after it
                     commits (satisfied and held: the grasp has settled), or when it gives up
                     (patience), or after max_trial_s. Each person makes `attempts` runs per
                     mode, eq (6)'s history term fed from its previous runs in that mode
    side, aligned    open loop (`app.operator.open_loop`): a sampled trajectory that does not
                     watch the robot, to the handle with heading normal - U(side_offset_rad)
                     (side) or the normal (aligned); the trial lasts as long as it
    deviate          open loop, the paper's Fig. 6 story: starting at the normal's heading
                     (close to the goal early) and deviating late by U(deviate_rad)

Success: the robot's final pose is within `success_radius_m` of the TRUE handle position
and within `success_heading_rad` of the normal (closed loop: the settled pose after a commit;
a run that ends by giving up fails). Time: the trial's duration for the closed-loop
operator (it decides when it is done); for an open-loop one, the time from which the robot
stays in the success region to the end (its settling time), or the whole trial on failure.

Per trajectory the metrics of Section IV-D (dsteleop.arbitration.metrics) are taken over the
actions of the trial: cosine distance (the paper's sum over actions, the mean per action
beside it) and ratio of agreement of U_human vs U_out, both skipping the same idle actions
(`metrics.idle_actions`); the paper's definitions in the arbitration's units (m/s, rad/s) are
the headline, and `metric_variants` adds actions over the velocity limits, per group, by
phase and a labelled dead-band variant. Over trajectories, as the paper's Table I: success
as a Laplace estimate, time, cosine distance and agreement as geometric means (arithmetic
means beside them, labelled); censored times (the operator gave up, the time limit, an
open-loop trial that never settled) are counted. `divergence` holds the Jensen-Shannon
divergences of Fig. 8's pairs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.operator.closed_loop import ClosedLoopOperator, Intention, OperatorProfile
from dsteleop.app.operator.open_loop import (
    OperatorStrategy,
    OperatorTrajectory,
    sample_trajectory,
    stack,
)
from dsteleop.app.operator.world import CommandDelay, Impairments
from dsteleop.app.session.trace import Trace
from dsteleop.app.study.grasps import Grasps, settle_after
from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    ArbitrationStep,
    HandState,
    Mode,
    RowModes,
    dim_names,
    make_arbiter,
    metrics,
    registered,
    so3_exp,
)
from dsteleop.arbitration.history import history_terms
from dsteleop.arbitration.se3 import ROT, TRANS
from dsteleop.arbitration.se3 import stack as stack_states
from dsteleop.errors import ConfigError, ContractError
from dsteleop.robot.task import Phase

Array = NDArray[np.float64]
OperatorKind = Literal["closed-loop", "side", "aligned", "deviate"]
OPERATORS: tuple[str, ...] = ("closed-loop", "side", "aligned", "deviate")
OPEN_LOOP: tuple[str, ...] = ("side", "aligned", "deviate")


def all_modes() -> tuple[Mode, ...]:
    """Every registered mode (`arbitration.modes`) but those that read the robot's confidence
    in its goal (`ModeSpec.reads_confidence`: the study tells the robot its goal, so they
    would repeat the modes they temper; `--modes` runs them), S and DS first: the study's
    default."""
    rest = (m for m in registered() if m not in (Mode.S, Mode.DS) and not m.spec.reads_confidence)
    return (Mode.S, Mode.DS, *rest)


def __getattr__(name: str) -> Any:
    """`ALL_MODES`: the registered modes now (`all_modes`), read when asked for."""
    if name == "ALL_MODES":
        return all_modes()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


SCHEMA = "dsteleop.sim_summary/2"
DEAD_BAND_MPS = 0.001  # the dead-band variant skips output actions slower than this [m/s]
HIST_BINS = 16
PATH_STRIDE = 3  # keep every 3rd tick of the example paths (Fig. 5b)
PHASE_EDGES = np.linspace(0.0, 1.0, 11)  # deciles of each trial for the by-phase metrics
Y_ONLY_MPS = 0.02  # operator speed along y above which a y-only action counts [m/s]


#: The fields of ArbitrationConfig that the study's simulated operators read (their speed caps
#: sit just under the robot's velocity limits: `SimConfig.operator_profile`, `planar_strategy`).
#: Changing one changes the simulated person, not only the arbitration.
OPERATOR_FIELDS: tuple[str, ...] = ("v_max_mps", "w_max_radps", "g_max_per_s")


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
        operator: `closed-loop` (watches the robot; the default), or open loop: `side` (the
            paper's scenario), `aligned` (agrees on every dimension), `deviate` (Fig. 6).
        modes: arbitration modes, each run on every trajectory.
        dt_s: tick [s].
        start_xy_m: start position [m]; start heading `start_heading_rad` [rad].
        handle_xy_m: handle position [m].
        handle_normal_rad: heading of the grasp normal [rad].
        success_radius_m: R of the success test [m].
        success_heading_rad: delta of the success test [rad].
        world: the impairments (`Impairments`): the robot's goal noise per position axis
            (every operator kind), and for the closed-loop operator the teleoperation delay
            (both ways) and the single camera view's perception noise.
        goal_heading_sigma_rad: standard deviation of the robot's goal heading [rad].
        side_offset_rad: interval of the side (and closed-loop) operator's heading offset from
            the normal [rad]: it prefers to grasp the handle a little from the side.
        deviate_rad: interval of the deviate operator's late heading deviation [rad].
        operator_tolerance_m: the closed-loop operator is satisfied within this of its
            target [m] (half the success radius R: a person aims tighter than the task needs).
        operator_tolerance_rad: ... and within this of its own heading [rad] (half the
            task's delta: 0.175 of 0.35). After resistance it settles for the task itself:
            the true handle and the normal, within R and delta (docs/operator.md).
        grasp_s: after the operator commits (satisfied and held: it grasps), the grasp
            reaches the robot `world.delay_s` later and the fingers take this long to close;
            the trial ends then, and success is judged on that settled pose [s].
        attempts: runs each simulated person makes in each mode (the paper: three runs per
            trial); eq (6)'s history term of a run is fed from the person's previous runs in
            that mode.
        lead_probability: share of operators who move along y before x.
        max_trial_s: a closed-loop trial ends after this long in any case [s].
        profile: the closed-loop person (None: `OperatorProfile()` capped at the robot's
            velocity limits).
        example: index of the trajectory drawn in the per-trajectory figures; None picks
            the first one that moves y before x.
        max_paths: trajectories whose paths are kept for the distribution figure.
        arbitration: arbitration hyper-parameters.
        strategy: operator strategy; None gives planar_strategy(arbitration).
        grasps: the disagreement world (`app.study.grasps.Grasps`: two right grasps, the
            robot going to one, each closed-loop person preferring one and adapting with its
            own probability), or None: the one grasp at the normal (the default world).
    """

    trajectories: int = 1000
    seed: int = 0
    operator: OperatorKind = "closed-loop"
    modes: tuple[Mode, ...] = field(default_factory=all_modes)
    dt_s: float = 1.0 / 30.0
    start_xy_m: tuple[float, float] = (0.0, 0.0)
    start_heading_rad: float = 0.0
    handle_xy_m: tuple[float, float] = (0.30, 0.40)
    handle_normal_rad: float = math.pi / 4
    success_radius_m: float = 0.03
    success_heading_rad: float = 0.35
    world: Impairments = field(default_factory=Impairments)
    goal_heading_sigma_rad: float = 0.0
    side_offset_rad: tuple[float, float] = (0.15, 0.30)
    deviate_rad: tuple[float, float] = (0.5, 0.8)
    operator_tolerance_m: float = 0.015
    operator_tolerance_rad: float = 0.175
    grasp_s: float = 0.5
    attempts: int = 3
    lead_probability: float = 0.8
    max_trial_s: float = 60.0
    profile: OperatorProfile | None = None
    example: int | None = None
    max_paths: int = 200
    arbitration: ArbitrationConfig = field(default_factory=ArbitrationConfig)
    strategy: OperatorStrategy | None = None
    grasps: Grasps | None = None

    def __post_init__(self) -> None:
        if isinstance(self.trajectories, bool) or not isinstance(self.trajectories, int):
            raise ConfigError(f"trajectories must be an integer, got {self.trajectories!r}")
        if self.trajectories < 1:
            raise ConfigError(f"trajectories must be >= 1, got {self.trajectories}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed}")
        if self.operator not in OPERATORS:
            raise ConfigError(
                f"unknown operator {self.operator!r} (choose from {', '.join(OPERATORS)})"
            )
        if not self.modes or len(set(self.modes)) != len(self.modes):
            raise ConfigError("modes must be a non-empty list without repeats")
        for name in (
            "dt_s", "success_radius_m", "success_heading_rad", "operator_tolerance_m",
            "operator_tolerance_rad", "max_trial_s",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be finite and > 0, got {v!r}")
        if not isinstance(self.world, Impairments):
            raise ConfigError(f"world must be an Impairments, got {self.world!r}")
        if isinstance(self.attempts, bool) or not isinstance(self.attempts, int):
            raise ConfigError(f"attempts must be an integer, got {self.attempts!r}")
        if self.attempts < 1:
            raise ConfigError(f"attempts must be >= 1, got {self.attempts}")
        for name in ("goal_heading_sigma_rad", "grasp_s"):
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
        if self.grasps is not None:
            if not isinstance(self.grasps, Grasps):
                raise ConfigError(f"grasps must be a Grasps, got {self.grasps!r}")
            self.grasps.check(self.success_heading_rad, self.operator_tolerance_rad)

    @property
    def grasp_headings(self) -> tuple[float, ...]:
        """The headings of the task's grasps [rad]: the normal alone, or each of `grasps`."""
        n = self.handle_normal_rad
        return (n,) if self.grasps is None else tuple(n + o for o in self.grasps.offsets_rad())

    @property
    def robot_heading(self) -> float:
        """The heading of the grasp the robot's policy goes to (before its noise) [rad]."""
        g = self.grasps
        return self.handle_normal_rad + (0.0 if g is None else g.offset_of(g.robot_grasp))

    @property
    def operator_strategy(self) -> OperatorStrategy:
        if self.strategy is not None:
            return self.strategy
        base = planar_strategy(self.arbitration)
        if self.operator == "deviate":  # the heading turns late
            return dataclasses.replace(base, rotation_onset=(0.6, 0.8), rotation_end=(0.9, 1.0))
        return base

    @property
    def operator_profile(self) -> OperatorProfile:
        a = self.arbitration
        return (self.profile or OperatorProfile()).for_robot(
            a.v_max_mps, a.w_max_radps, a.g_max_per_s
        )

    @property
    def closed_loop(self) -> bool:
        return self.operator == "closed-loop"

    @property
    def runs(self) -> int:
        """Runs per person and mode: `attempts` for the closed-loop operator; one for an
        open-loop operator (the paper's simulation: no previous attempts)."""
        return self.attempts if self.closed_loop else 1

    @property
    def start_heading(self) -> float:
        """The start heading: the normal's for the deviate operator (close early)."""
        return self.handle_normal_rad if self.operator == "deviate" else self.start_heading_rad

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (modes by name, nested configs as dicts)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "modes":
                v = [m.value for m in v]
            elif f.name in ("arbitration", "world"):
                v = v.to_dict()
            elif f.name == "strategy":
                v = _jsonable(dataclasses.asdict(self.operator_strategy))
            elif f.name == "profile":
                v = _jsonable(dataclasses.asdict(self.operator_profile))
            elif f.name == "grasps":
                if v is None:  # the default world's summary stays as it was
                    continue
                v = v.to_dict()
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
    normal: float | Sequence[float],
    R: float,
    delta: float,
) -> NDArray[np.bool_]:
    """The success test: within R [m] of the handle and within delta [rad] of its normal (of
    any one of its grasps' normals, where it has several).

    Args:
        xy: (..., 2) positions [m].
        heading: (...) headings [rad].
        handle_xy: (2,) handle position [m].
        normal: heading of the grasp normal [rad], or of each grasp.
        R: radius [m].
        delta: heading tolerance [rad].
    """
    d = np.linalg.norm(np.asarray(xy) - np.asarray(handle_xy), axis=-1)
    normals = (normal,) if isinstance(normal, (int, float)) else tuple(normal)
    aligned = np.abs(wrap(np.asarray(heading) - normals[0])) <= delta
    for n in normals[1:]:
        aligned = aligned | (np.abs(wrap(np.asarray(heading) - n)) <= delta)
    return np.asarray((d <= R) & aligned)


def grasp_of(cfg: SimConfig, heading: Array) -> NDArray[np.int64]:
    """The index of the grasp (`cfg.grasp_headings`) nearest in heading to each `heading`."""
    h = np.asarray(heading)[..., None]
    return np.asarray(np.argmin(np.abs(wrap(h - np.asarray(cfg.grasp_headings))), axis=-1))


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


def _draws(cfg: SimConfig, index: int) -> tuple[np.random.Generator, Array]:
    """Trajectory `index`'s generator and the robot's goal, drawn first (every operator kind
    gets the same goal noise)."""
    rng = np.random.default_rng([cfg.seed, index])
    hx, hy = cfg.handle_xy_m
    noise = rng.standard_normal(3)
    sigma = cfg.world.goal_sigma_m
    robot_goal = np.array(
        [
            hx + sigma * noise[0],
            hy + sigma * noise[1],
            cfg.robot_heading + cfg.goal_heading_sigma_rad * noise[2],
        ]
    )
    return rng, robot_goal


def robot_goal(cfg: SimConfig, index: int, attempt: int) -> Array:
    """The robot's goal (x, y, heading) in run `attempt` of trajectory `index`: run 0's is
    `_draws`'; a later run's goal noise is drawn afresh from (seed, index, 2, attempt)."""
    if attempt == 0:
        return _draws(cfg, index)[1]
    noise = np.random.default_rng([cfg.seed, index, 2, attempt]).standard_normal(3)
    hx, hy = cfg.handle_xy_m
    sigma = cfg.world.goal_sigma_m
    return np.array(
        [
            hx + sigma * noise[0],
            hy + sigma * noise[1],
            cfg.robot_heading + cfg.goal_heading_sigma_rad * noise[2],
        ]
    )


def sample_trial(cfg: SimConfig, index: int) -> Trial:
    """Trajectory `index` of an open-loop operator: seeded by (seed, index) only."""
    rng, robot_goal = _draws(cfg, index)
    hx, hy = cfg.handle_xy_m
    offset = 0.0
    if cfg.operator in ("side", "closed-loop"):
        offset = float(rng.uniform(*cfg.side_offset_rad))
    elif cfg.operator == "deviate":
        offset = -float(rng.uniform(*cfg.deviate_rad))
    op_goal = np.array([hx, hy, cfg.handle_normal_rad - offset])
    start = planar_state(*cfg.start_xy_m, cfg.start_heading)  # type: ignore[arg-type]
    goal = planar_state(*op_goal)
    tr = sample_trajectory(start, goal, cfg.dt_s, rng, cfg.operator_strategy)
    return Trial(index, tr, robot_goal, op_goal)


@dataclass(frozen=True)
class ClosedTrial:
    """The random part of one closed-loop trajectory.

    Attributes:
        index: trajectory index n.
        robot_goal: (3,) x [m], y [m], heading [rad] the robot aims for (noisy).
        operator_goal: (3,) the operator's own target: the true handle, its heading.
        lead: the operator moves along y before x.
        turn_within_m: it turns the heading only within this of the handle [m].
        seed: the seed of its own generator (the same in every mode: paired).
        grasp: the grasp it prefers (an index of `GRASP_NAMES`; 0 in the default world).
        adaptability: its probability of switching to the robot's grasp at a resistance
            pause (1 in the default world: it settles at its first).
        settle_after: the resistance pause at which it settles (1 in the default world).
    """

    index: int
    robot_goal: Array
    operator_goal: Array
    lead: bool
    turn_within_m: float
    seed: tuple[int, int, int]
    grasp: int = 0
    adaptability: float = 1.0
    settle_after: int = 1


def sample_closed_trial(cfg: SimConfig, index: int) -> ClosedTrial:
    """Trajectory `index` of the closed-loop operator: seeded by (seed, index) only."""
    rng, robot_goal = _draws(cfg, index)
    hx, hy = cfg.handle_xy_m
    offset = float(rng.uniform(*cfg.side_offset_rad))
    lead = bool(rng.random() < cfg.lead_probability)
    turn_within = float(rng.uniform(0.05, 0.15))
    op_goal = np.array([hx, hy, cfg.handle_normal_rad - offset])
    seed = (cfg.seed, index, 1)
    g = cfg.grasps
    if g is None:
        return ClosedTrial(index, robot_goal, op_goal, lead, turn_within, seed)
    # The disagreement world: drawn after the default world's draws, which stay the same.
    prefers_robot = bool(rng.random() < g.prefer_robot_share)
    grasp = g.robot_index if prefers_robot else 1 - g.robot_index
    alpha = float(rng.uniform(*g.adaptability))
    after = settle_after(float(rng.random()), alpha, NEVER_SETTLES)
    op_goal = np.array([hx, hy, cfg.grasp_headings[grasp]])
    return ClosedTrial(
        index, robot_goal, op_goal, lead, turn_within, seed, grasp, alpha, after
    )  # fmt: skip


#: A pause count no trial reaches (a person of adaptability 0 never switches).
NEVER_SETTLES = 1_000_000


def closed_operator(
    cfg: SimConfig, trials: Sequence[ClosedTrial], attempt: int = 0
) -> ClosedLoopOperator:
    """The operators of `trials`, fresh (each mode starts them from the same state), in run
    `attempt` (each run its own random stream: (seed, n, 1) for run 0, then (seed, n, 1, a)).

    Each wants the robot at the true handle with its own heading within its own tolerance;
    after resistance it settles for the task: the true handle and the normal (in the
    disagreement world: the robot's grasp), within the success radius and heading tolerance
    (the via stage of a y-first person is unchanged), at its first resistance pause (in the
    disagreement world: at its own, `ClosedTrial.settle_after`)."""
    N = len(trials)
    sx, sy = cfg.start_xy_m
    h0 = cfg.start_heading
    goals = np.stack([t.operator_goal for t in trials])
    lead = np.array([t.lead for t in trials])
    # Stage 0: along y first (to the handle's y, the start's x and heading) when leading;
    # stage 1: the handle itself, with the operator's own heading.
    via = np.stack([np.full(N, sx), goals[:, 1], np.full(N, h0)], -1)
    first = np.where(lead[:, None], via, goals)
    targets = planar_state(
        np.stack([first[:, 0], goals[:, 0]], 1),
        np.stack([first[:, 1], goals[:, 1]], 1),
        np.stack([first[:, 2], goals[:, 2]], 1),
    )
    final = (cfg.operator_tolerance_m, cfg.operator_tolerance_rad, 1.0)
    passing = (0.05, math.pi, 1.0)  # a via point: near it in position, any heading
    tolerance = np.stack(
        [np.where(lead[:, None], passing, final), np.broadcast_to(final, (N, 3))], 1
    )
    # The via stage counts y only: the operator brings the robot to the handle's y first,
    # whatever x the robot has meanwhile.
    # The task's dimensions are x, y and the heading (z, roll, pitch never count).
    y_only = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    planar = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    mask = np.stack([np.where(lead[:, None], y_only, planar), np.tile(planar, (N, 1))], 1)
    hx, hy = cfg.handle_xy_m
    task = planar_state(
        np.stack([first[:, 0], np.full(N, hx)], 1),
        np.stack([first[:, 1], np.full(N, hy)], 1),
        np.stack([first[:, 2], np.full(N, cfg.robot_heading)], 1),
    )
    accept = (cfg.success_radius_m, cfg.success_heading_rad, 1.0)
    task_tolerance = np.stack(
        [np.where(lead[:, None], passing, accept), np.broadcast_to(accept, (N, 3))], 1
    )
    intention = Intention(
        targets, tolerance, mask, np.where(lead, 2, 1).astype(np.int64),
        np.array([t.turn_within_m for t in trials]), task, task_tolerance,
        None if cfg.grasps is None else np.array([t.settle_after for t in trials]),
    )  # fmt: skip
    start = planar_state(np.full(N, sx), np.full(N, sy), np.full(N, h0))
    rngs = [np.random.default_rng(t.seed if attempt == 0 else (*t.seed, attempt)) for t in trials]
    return ClosedLoopOperator(intention, start, cfg.operator_profile, rngs, world=cfg.world)


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
    lengths: NDArray[np.int64]  # (N,) states of each trial (closed loop: mode-dependent)
    gave_up: NDArray[np.bool_]  # (N,) the closed-loop operator gave up (False for open loop)
    n_idle: NDArray[np.int64]  # (N,) idle actions, skipped by both cosine distance and agreement
    hand_hist: NDArray[np.int64]  # the hand's (x, y, heading) histogram in this mode
    hand_paths: Array  # (P, T', 3) the hand's paths of the first trajectories
    variants: dict[str, Array]  # per-trajectory metric variants (`metric_variants`)
    committed: NDArray[np.bool_]  # (N,) the closed-loop operator committed (True for open loop)
    hand_final: Array  # (N, 3) the hand's final x, y, heading
    attempt: NDArray[np.int64]  # (N,) the run of each row (0 first)
    history_norm: Array  # (N,) |eq (6)'s history term| (L1) the run's arbitration received
    settled: NDArray[np.bool_]  # (N,) the closed-loop operator settled (the task's or robot's way)


#: ModeResult's fields that are not one row per trial (summed or kept for the first paths).
_POOLED = ("hist", "paths", "hand_hist", "hand_paths")


def concat_results(parts: Sequence[ModeResult]) -> ModeResult:
    """The rows of `parts` one after the other (histograms summed, paths concatenated)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(ModeResult):
        vals = [getattr(p, f.name) for p in parts]
        if f.name in ("hist", "hand_hist"):
            out[f.name] = np.sum(vals, axis=0)
        elif f.name in ("paths", "hand_paths"):
            out[f.name] = _cat_paths(vals)
        elif f.name == "variants":
            out[f.name] = {k: np.concatenate([v[k] for v in vals]) for k in vals[0]}
        else:
            out[f.name] = np.concatenate(vals)
    return ModeResult(**out)


def take_rows(r: ModeResult, order: NDArray[np.intp]) -> ModeResult:
    """The rows `order` of r (the pooled fields as they are)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(ModeResult):
        v = getattr(r, f.name)
        if f.name in _POOLED:
            out[f.name] = v
        elif f.name == "variants":
            out[f.name] = {k: x[order] for k, x in v.items()}
        else:
            out[f.name] = v[order]
    return ModeResult(**out)


def _cat_paths(arrs: Sequence[Array]) -> Array:
    arrs = [a for a in arrs if a.shape[0] > 0]
    if not arrs:
        return np.zeros((0, 1, 3))
    T = max(a.shape[1] for a in arrs)
    return np.concatenate(
        [np.pad(a, ((0, 0), (0, T - a.shape[1]), (0, 0)), constant_values=np.nan) for a in arrs]
    )


@dataclass(frozen=True)
class ChunkResult:
    """Results of a contiguous set of trajectories under every mode: `runs` rows per
    trajectory in the modes' results (row n * runs + a: run a of trajectory n)."""

    indices: NDArray[np.int64]
    lengths: NDArray[np.int64]
    lead: NDArray[np.bool_]
    operator_hist: NDArray[np.int64]
    operator_paths: Array
    modes: dict[str, ModeResult]


def first_lead_index(cfg: SimConfig) -> int:
    """The first trajectory that moves y before x (0 if none): the default example."""
    sample = sample_closed_trial if cfg.closed_loop else sample_trial
    for i in range(cfg.trajectories):
        if sample(cfg, i).lead:
            return i
    return 0


def hist_ranges(cfg: SimConfig) -> Array:
    """(3, 2) ranges of the trajectory histograms: the start-handle box with a margin."""
    sx, sy = cfg.start_xy_m
    hx, hy = cfg.handle_xy_m
    m = 0.1
    h = [
        cfg.start_heading,
        cfg.handle_normal_rad,
        cfg.handle_normal_rad - cfg.side_offset_rad[1],
        *cfg.grasp_headings,
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
    """Sample trajectories `indices` and run them under every mode of `cfg`, in one batch.

    The batch holds one row per (mode, trajectory): every mode sees the same operator (the
    closed-loop operators of one trajectory are copies with the same seed) and the same goal
    noise, and the operators, the bookkeeping and the metrics are stepped once for all modes.

    Args:
        cfg: the study.
        indices: trajectory indices.
        on_progress: called with counts of trajectory-modes done (for a progress bar).
    """
    idx = np.asarray(indices, dtype=np.int64)
    ranges = hist_ranges(cfg)
    n_paths = int(np.clip(cfg.max_paths - idx[0], 0, len(idx))) if len(idx) else 0
    C, N, A = len(cfg.modes), len(idx), cfg.runs
    runs: list[dict[str, ModeResult]] = []
    history: Array | None = None
    terminals: list[Array] = []  # per run, the hands' final (x, y, heading), (C N, 3)
    tape: _Tape | None = None  # one recording for every run (its pages are touched once)
    for a in range(A):
        goals, lead, hands = _hands_for(cfg, idx, C, a)
        tape = _Tape(hands.T, C * N) if tape is None else tape
        runs.append(
            _run_modes(
                cfg, cfg.modes, hands, goals, ranges, n_paths if a == 0 else 0, on_progress,
                history, a, tape,
            )
        )  # fmt: skip
        if a + 1 < A:  # eq (6)'s last term for the next run: this person's runs so far
            terminals.append(np.concatenate([runs[a][m.value].hand_final for m in cfg.modes]))
            history = _history(cfg, np.stack(terminals, 1))
    # Row n * A + a: run a of trajectory n (so chunks concatenate in trajectory order).
    order = np.arange(N * A).reshape(A, N).T.ravel()
    modes = {
        m.value: take_rows(concat_results([r[m.value] for r in runs]), order) for m in cfg.modes
    }
    first = modes[cfg.modes[0].value]
    return ChunkResult(idx, first.lengths, lead, first.hand_hist, first.hand_paths, modes)


def _history(cfg: SimConfig, terminals: Array) -> Array:
    """Eq (6)'s history term per row (R, 6) from the rows' previous runs: their hands'
    final planar poses (R, A, 3); every run starts at the start pose."""
    R, A = terminals.shape[:2]
    sx, sy = cfg.start_xy_m
    h0 = cfg.start_heading
    starts = planar_state(np.full((R, A), sx), np.full((R, A), sy), np.full((R, A), h0))
    ends = planar_state(terminals[..., 0], terminals[..., 1], terminals[..., 2])
    return history_terms(starts, ends, cfg.arbitration.still_offset(0))


def _hands_for(
    cfg: SimConfig, idx: NDArray[np.int64], copies: int, attempt: int = 0
) -> tuple[Array, NDArray[np.bool_], _Hands]:
    """The robot goals (N, 3), lead flags (N,) and the hands of `copies` x N rows (one block
    of N per mode) of trajectories `idx`, in run `attempt`."""
    if cfg.closed_loop:
        closed = [sample_closed_trial(cfg, int(i)) for i in idx]
        goals = np.stack([robot_goal(cfg, int(i), attempt) for i in idx])
        lead = np.array([t.lead for t in closed], dtype=bool)
        delay = round(cfg.world.delay_s / cfg.dt_s)
        settle = delay + round(cfg.grasp_s / cfg.dt_s)
        T = round(cfg.max_trial_s / cfg.dt_s) + 1 + settle
        op = closed_operator(cfg, closed * copies, attempt)
        return goals, lead, _ClosedHands(op, T, delay, settle)
    trials = [sample_trial(cfg, int(i)) for i in idx]
    stacked, lengths = stack([t.operator for t in trials])
    goals = np.stack([t.robot_goal for t in trials])
    lead = np.array([t.lead for t in trials], dtype=bool)
    return goals, lead, _OpenHands(_time_major(stacked), lengths, copies)


@dataclass(frozen=True)
class Example:
    """One trajectory under one mode, every tick kept (the per-trajectory figures).

    Attributes:
        trace: the ticks as a replay trace: T = L - 1 ticks of a trial of L states (tick k
            takes the robot from state k to state k + 1, at time t_{k+1}).
        t_s: (L,) the states' times [s].
        hand: (L, 3) the hand's x, y, heading (closed loop: in this mode).
        robot: (L, 3) the robot's x, y, heading.
    """

    trace: Trace
    t_s: Array
    hand: Array
    robot: Array


def example(cfg: SimConfig, index: int, mode: Mode) -> Example:
    """Run trajectory `index` under `mode` alone and keep every tick."""
    goals, _, source = _hands_for(cfg, np.array([index]), 1)
    goal = goals[0]
    steps: list[ArbitrationStep] = []
    robot, L_all, hand = _simulate(cfg, (mode,), source, goals, record=steps)
    L = int(L_all[0])
    first = steps[: L - 1]
    step = ArbitrationStep(
        **{k: np.stack([getattr(s, k)[0] for s in first]) for k in STEP_ARRAYS},
        X_next=stack_states([s.X_next.take(0) for s in first]),
    )
    t = np.arange(L, dtype=np.float64) * np.float64(cfg.dt_s)
    tr = Trace(
        name=f"trajectory {index}",
        mode=mode,
        dims=dim_names(0),
        t_s=t[1:],
        arbitrated=np.ones(L - 1, dtype=bool),
        step=step,
        p_human=np.concatenate([hand[1:L, 0, :2], np.zeros((L - 1, 1))], -1),
        p_robot=np.concatenate([robot[1:L, 0, :2], np.zeros((L - 1, 1))], -1),
        p_goal=np.tile([*goal[:2], 0.0], (L - 1, 1)),
        phases=(Phase.PICK,) * (L - 1),
        outcome=None,
        time_s=float((L - 1) * cfg.dt_s),
        v_max=cfg.arbitration.v_max(0),
    )
    return Example(tr, t, hand[:L, 0], robot[:L, 0])


def trace(cfg: SimConfig, index: int, mode: Mode) -> Trace:
    """Run one trajectory under one mode and keep every tick (`Example.trace`)."""
    return example(cfg, index, mode).trace


class _Hands:
    """Where a simulation's hands come from, tick by tick (open or closed loop), for C x N
    rows: C copies (one per mode) of N trajectories, row j = c N + n."""

    T: int  # the most states a trial can have
    lengths: NDArray[np.int64]  # (C N,) states of each trial (closed loop: T until it ends)
    gave_up: NDArray[np.bool_]  # (C N,) the operator gave up (closed loop)
    committed: NDArray[np.bool_]  # (C N,) the operator committed (open loop: all)
    settled: NDArray[np.bool_]  # (C N,) the operator settled (closed loop)

    def start(self) -> HandState:
        raise NotImplementedError

    def next(self, k: int, t_s: float) -> tuple[HandState, HandState]:
        """(hand at state k + 1, hand at state k) of the current rows."""
        raise NotImplementedError

    def observe(self, t_s: float, X: HandState) -> None:
        """The robot at t_s (closed loop: what the operators see, later)."""

    def ended(self, rows: NDArray[np.int64], k: int) -> None:
        """Record which of `rows` ended their trial at state k + 1."""

    def keep(self, keep: NDArray[np.bool_], k: int) -> None:
        """Only the current rows `keep` go on after tick k."""
        raise NotImplementedError


class _OpenHands(_Hands):
    """Precomputed hands, time-major (T, N, ...): the operator does not watch; every copy
    reads the same trajectory."""

    def __init__(self, hands_tm: HandState, lengths: NDArray[np.int64], copies: int) -> None:
        self.pos, self.rot, self.opn = hands_tm.position, hands_tm.rotation, hands_tm.openness
        N = lengths.shape[0]
        self.lengths = np.tile(lengths, copies)
        self.gave_up = np.zeros(copies * N, dtype=bool)
        self.committed = np.ones(copies * N, dtype=bool)
        self.settled = np.zeros(copies * N, dtype=bool)
        self.T = int(hands_tm.position.shape[0])
        self.cols = np.tile(np.arange(N), copies)  # the trajectory of each current row

    def start(self) -> HandState:
        return self._at(0)

    def _at(self, k: int) -> HandState:
        c = self.cols
        return HandState(self.pos[k, c], self.rot[k, c], self.opn[k, c])

    def next(self, k: int, t_s: float) -> tuple[HandState, HandState]:
        return self._at(k + 1), self._at(k)

    def keep(self, keep: NDArray[np.bool_], k: int) -> None:
        self.cols = self.cols[keep]


class _ClosedHands(_Hands):
    """Hands from closed-loop operators, who watch the robot (one operator per row), as the
    robot receives them: `delay` ticks late (the command path of the teleoperation delay).
    A trial ends when its operator gives up, or `settle` ticks after it commits (the grasp
    reaches the robot and the fingers close): success is judged on that settled pose."""

    def __init__(self, op: ClosedLoopOperator, T: int, delay: int = 0, settle: int = 0) -> None:
        self.op = op
        self.T = T
        self.settle = settle
        N = op.start.position.shape[0]
        self.lengths = np.full(N, T, dtype=np.int64)
        self.gave_up = np.zeros(N, dtype=bool)  # by original row (the operator compacts)
        self.committed = np.zeros(N, dtype=bool)
        self.settled = np.zeros(N, dtype=bool)
        self.line = CommandDelay(op.start, delay)
        self.prev = op.start

    def start(self) -> HandState:
        return self.op.start

    def next(self, k: int, t_s: float) -> tuple[HandState, HandState]:
        H = self.line.push(self.op.hand(t_s))
        prev, self.prev = self.prev, H
        return H, prev

    def observe(self, t_s: float, X: HandState) -> None:
        self.op.observe(t_s, X)

    def ended(self, rows: NDArray[np.int64], k: int) -> None:
        newly = self.op.done & (self.lengths[rows] == self.T)
        if not newly.any():
            return
        committed = self.op.committed[newly]
        ended = rows[newly]
        self.lengths[ended] = np.minimum(k + 2 + np.where(committed, self.settle, 0), self.T - 1)
        self.gave_up[ended] = self.op.gave_up[newly]
        self.committed[ended] = committed
        self.settled[ended] = self.op.settled[newly]

    def keep(self, keep: NDArray[np.bool_], k: int) -> None:
        self.op.select(keep)
        self.line.select(keep)
        self.prev = self.prev.take(keep)


#: Ticks between the checks for ended rows in `_simulate` (the rows that ended are dropped
#: there), and the block of ticks `_Tape` buffers between two of them.
_CHECK_TICKS = 16


def _planar_into(out: Array, X: HandState) -> None:
    """Write the states X (n,) as planar poses into out (n, 3): x, y, heading."""
    out[:, :2] = X.position[:, :2]
    out[:, 2] = heading_of(X.rotation)


def _rows_of(a: Array) -> NDArray[np.void]:
    """(..., J, w) float64 with C-contiguous rows -> (..., J) of one opaque w * 8-byte item
    per row: a row is then copied as one item (a fancy-indexed copy of rows ~3x faster)."""
    return a.view(np.dtype((np.void, a.shape[-1] * a.itemsize)))[..., 0]


class _Tape:
    """The recording of one simulation of J rows of up to T states, time-major (one
    contiguous block per tick), reusable by the next run of the same shape (a run touches
    fresh memory pages only once per chunk, not once per run).

    The current rows' ticks are buffered in a block of `_CHECK_TICKS` ticks (copied as they
    come) and scattered to their rows at once when the batch's rows change (`flush`). The
    states are uninitialised where not written: every state before a row's length is
    written (a row leaves the batch only after its trial ended) and `_simulate` sets the rest
    to NaN. The actions start at zero and count only where `acted` (set by `close` from the
    trials' lengths; elsewhere they hold a later tick of the row, an earlier run's finite
    values or zero).

    Attributes:
        robot, hand: (T, J, 3) x, y and heading per state.
        U_human, U_out: (T - 1, J, 6) the actions of each tick.
        acted: (T - 1, J) the tick belongs to the row's trial.
    """

    def __init__(self, T: int, J: int) -> None:
        self.shape = (T, J)
        self.robot, self.hand = np.empty((T, J, 3)), np.empty((T, J, 3))
        self.U_human, self.U_out = np.zeros((T - 1, J, 6)), np.zeros((T - 1, J, 6))
        self.acted = np.zeros((T - 1, J), dtype=bool)
        B = _CHECK_TICKS
        # The block: tick k's states (at k + 1) and actions (at k) of the current rows.
        self._block = tuple(np.empty((B, J, w)) for w in (3, 3, 6, 6))
        self._from = 0  # the block's first tick
        self._ticks = 0  # ticks in the block

    def start(self, T: int, J: int) -> _Tape:
        """Ready for a run of the same shape."""
        if (T, J) != self.shape:
            raise ContractError(f"a tape of {self.shape} for a run of {(T, J)}")
        self._from = self._ticks = 0
        return self

    def put(self, k: int, X: HandState, H: HandState, U_h: Array, U_out: Array) -> None:
        """Tick k of the current rows: the robot X and the hand H at state k + 1 and the
        actions. Ticks come in order; `flush` at least every `_CHECK_TICKS` ticks."""
        i = k - self._from
        n = U_h.shape[0]
        robot, hand, uh, uo = self._block
        _planar_into(robot[i, :n], X)
        _planar_into(hand[i, :n], H)
        uh[i, :n], uo[i, :n] = U_h, U_out
        self._ticks = i + 1

    def flush(self, rows: NDArray[np.int64]) -> None:
        """Scatter the block's ticks to `rows` (the rows they were of)."""
        k0, B, n = self._from, self._ticks, rows.size
        states = slice(k0 + 1, k0 + 1 + B)
        actions = slice(k0, k0 + B)
        targets = (
            self.robot[states],
            self.hand[states],
            self.U_human[actions],
            self.U_out[actions],
        )
        for full, block in zip(targets, self._block, strict=True):
            if n == self.shape[1]:
                full[...] = block[:B]
            else:
                _rows_of(full)[:, rows] = _rows_of(block[:B, :n])
        self._from, self._ticks = k0 + B, 0

    def close(self, lengths: NDArray[np.int64]) -> None:
        """The trials' lengths (J,) known: tick k belongs to row j's trial iff k + 1 <
        lengths[j] (a row stays in the batch at least that long)."""
        np.less(np.arange(1, self.shape[0])[:, None], lengths[None, :], out=self.acted)


def _simulate(
    cfg: SimConfig,
    modes: Sequence[Mode],
    hands: _Hands,
    goals: Array,
    record: list[ArbitrationStep] | None = None,
    on_progress: Callable[[int], None] | None = None,
    history: Array | None = None,
    tape: _Tape | None = None,
) -> tuple[Array, NDArray[np.int64], Array]:
    """Step the batch of len(modes) x N rows (row j = m N + n: trajectory n under mode m)
    through time. Returns the robot's and the hand's (x, y, heading), time-major (T, C N, 3)
    each (T: the longest trial), NaN past the end of each trial, and the trials' lengths
    (states).

    One arbiter steps the mixed batch (`RowModes`). Rows whose trial has ended are
    dropped from the batch every few ticks (the arbitration is row-wise, so this changes no
    result, only the work). The states and the actions of the rows whose trial includes a
    tick go on `tape` (a fresh one when None; the returned poses are views of it);
    on_progress is called with counts of trials that ended; `record` (one mode only) gets
    every step; `history` (C N, 6) is eq (6)'s history term of each row (None: no previous
    runs).
    """
    C, N = len(modes), goals.shape[0]
    if record is not None and C != 1:
        raise ContractError("record needs a single mode")
    T, J = hands.T, C * N
    # One arbiter steps every mode's rows at once (a mixed batch: row j is in mode j // N).
    arb = make_arbiter(modes[0], cfg.arbitration)
    mixed = RowModes.of([m for m in modes for _ in range(N)]) if C > 1 else None
    state = arb.initial_state(6, batch=(J,))
    X0 = planar_state(
        np.full(J, cfg.start_xy_m[0]), np.full(J, cfg.start_xy_m[1]), np.full(J, cfg.start_heading)
    )
    g = np.tile(goals, (C, 1))
    G = planar_state(g[:, 0], g[:, 1], g[:, 2])
    rows = np.arange(J)
    hist = history
    X, Xp, X0r = X0, X0, X0
    H0 = hands.start()
    tape = (_Tape(T, J) if tape is None else tape).start(T, J)
    _planar_into(tape.robot[0], X)
    _planar_into(tape.hand[0], H0)
    hands.observe(0.0, X)
    reported = 0
    for k in range(T - 1):
        if k % _CHECK_TICKS == 0 and k > 0:
            tape.flush(rows)
            keep = hands.lengths[rows] > k + 1
            if on_progress is not None:
                done = int(J - rows.size + np.count_nonzero(~keep))
                if done > reported:
                    on_progress(done - reported)
                    reported = done
            if not keep.any():
                break
            if keep.sum() < 0.9 * rows.size:
                rows = rows[keep]
                state = state.select(keep)
                mixed = None if mixed is None else mixed.select(keep)
                X, Xp, X0r, H0, G = (h.take(keep) for h in (X, Xp, X0r, H0, G))
                hist = None if hist is None else hist[keep]
                hands.keep(keep, k)
        t_next = (k + 1) * cfg.dt_s
        H, Hp = hands.next(k, t_next)
        hands.ended(rows, k)
        inp = ArbitrationInput(
            X_human=H, X_human_prev=Hp, X_human_start=H0, X_current=X, X_prev=Xp, X_start=X0r,
            X_goal=G, dt=cfg.dt_s, history_term=hist,
        )  # fmt: skip
        # The study reads the actions and states only: eq (4)-(7) just where a mode's rule
        # reads them (every quantity when every step is recorded).
        state, step = arb.step(state, inp, mixed, every_quantity=record is not None)
        Xp, X = X, step.X_next
        hands.observe(t_next, X)
        tape.put(k, X, H, step.U_human, step.U_out)
        if record is not None:
            record.append(step)
    tape.flush(rows)
    if on_progress is not None and J > reported:
        on_progress(J - reported)
    lengths = np.minimum(hands.lengths, T)
    tape.close(lengths)
    T = int(lengths.max())  # the longest trial (closed loop: often far under the limit)
    past = np.arange(T)[:, None] >= lengths[None, :]

    def poses(p: Array) -> Array:
        out = p[:T]
        # Past a row's length the buffers hold whatever memory held: NaN there.
        np.copyto(out, np.nan, where=past[..., None])
        return out

    return poses(tape.robot), lengths, poses(tape.hand)


def _time_major(hands: HandState) -> HandState:
    """(N, T, ...) -> contiguous (T, N, ...) copies."""
    return HandState(
        *(
            np.ascontiguousarray(np.swapaxes(a, 0, 1))
            for a in (hands.position, hands.rotation, hands.openness)
        )
    )


def _run_modes(
    cfg: SimConfig,
    modes: Sequence[Mode],
    hands: _Hands,
    goals: Array,
    ranges: Array,
    n_paths: int,
    on_progress: Callable[[int], None] | None = None,
    history: Array | None = None,
    attempt: int = 0,
    tape: _Tape | None = None,
) -> dict[str, ModeResult]:
    """Simulate every mode in one batch (`_simulate`, recording on `tape`, a fresh one when
    None), then each mode's metrics (run `attempt`, with eq (6)'s history term `history`
    (C N, 6) per row, None for none). Every action of every trial is recorded, time-major;
    the metrics are computed afterwards over whole arrays with dsteleop.arbitration.metrics
    (the results hold no view of the tape)."""
    N = goals.shape[0]
    J = len(modes) * N
    tape = _Tape(hands.T, J) if tape is None else tape
    poses, lengths, hand = _simulate(
        cfg, modes, hands, goals, on_progress=on_progress, history=history, tape=tape
    )
    U_h_all, U_out_all, acted = tape.U_human, tape.U_out, tape.acted
    h_norm = np.zeros(J) if history is None else np.abs(history).sum(-1)
    out = {}
    for c, mode in enumerate(modes):
        part = slice(c * N, (c + 1) * N)
        L = lengths[part]
        Tm = int(L.max())  # this mode's longest trial
        out[mode.value] = _mode_result(
            cfg,
            poses[:Tm, part],
            L,
            hand[:Tm, part],
            hands.gave_up[part],
            hands.committed[part],
            U_h_all[: Tm - 1, part],
            U_out_all[: Tm - 1, part],
            acted[: Tm - 1, part],
            ranges,
            n_paths,
            attempt,
            h_norm[part],
            hands.settled[part],
        )
    return out


def _mode_result(
    cfg: SimConfig,
    poses_tm: Array,
    lengths: NDArray[np.int64],
    hand_tm: Array,
    gave_up: NDArray[np.bool_],
    committed: NDArray[np.bool_],
    U_h_tm: Array,
    U_out_tm: Array,
    acted_tm: NDArray[np.bool_],
    ranges: Array,
    n_paths: int,
    attempt: int = 0,
    history_norm: Array | None = None,
    settled: NDArray[np.bool_] | None = None,
) -> ModeResult:
    """One mode's per-trajectory results from its robot's and hand's states (T, N, 3) and
    its actions (T - 1, N, ...), time-major. A closed-loop trial succeeds only if its operator
    committed and the robot's settled pose (the trial's last) is in the success region."""
    T, N = poses_tm.shape[:2]
    # (N, T, ...) views, as for the actions below.
    poses, hand = np.swapaxes(poses_tm, 0, 1), np.swapaxes(hand_tm, 0, 1)
    # (N, T - 1, ...) views: the metrics reduce over the time axis wherever it lies in memory.
    U_h_all, U_out_all = np.swapaxes(U_h_tm, 0, 1), np.swapaxes(U_out_tm, 0, 1)
    acted = acted_tm.T
    # The actions' products per group (translation, rotation: the planar study has no
    # fingers), computed once; the literal definitions (the headline) weigh both alike.
    groups = metrics.ActionProducts.of_groups(U_h_all, U_out_all, (TRANS, ROT))
    lit = metrics.ActionProducts.combine(groups, (1.0, 1.0))
    c = metrics.cosine_distances(lit)
    cos = metrics.summarise_cosines(c, acted)
    ag = metrics.agreement_of(lit, acted)
    # By phase of the trial: tick k of a trial of L ticks is at phase k / (L - 1).
    n_bins = len(PHASE_EDGES) - 1
    k = np.arange(T - 1)[None, :]
    phase = k / (lengths[:, None] - 1)
    b = np.clip(np.searchsorted(PHASE_EDGES, phase, side="right") - 1, 0, n_bins - 1)
    counted = acted & ~np.isnan(c)  # the actions both metrics count (not idle)
    agrees = counted & (lit.dot > 0.0)
    # Per trajectory (N, 2, bins), so pooled sums do not depend on how rows were chunked.
    cos_bins = _bin_sum(b, np.where(counted, c, 0.0), n_bins)
    ph_cos = np.stack([cos_bins, _bin_sum(b, counted, n_bins)], 1)
    ph_ag = np.stack([_bin_sum(b, agrees, n_bins), _bin_sum(b, counted, n_bins)], 1)
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
    valid = np.arange(T)[None, :] < lengths[:, None]
    rows = np.arange(N)
    last = lengths - 1

    def inside(p: Array) -> NDArray[np.bool_]:
        return in_success_region(
            p[..., :2], p[..., 2], cfg.handle_xy_m, cfg.grasp_headings,
            cfg.success_radius_m, cfg.success_heading_rad,
        )  # fmt: skip

    if cfg.closed_loop:  # the operator decides when the trial is done: its settled pose
        success = inside(poses[rows, last]) & committed
        time_s = np.maximum(last, 1) * cfg.dt_s
    else:  # settling time: the first tick after the last one outside the region
        inside_all = inside(poses)
        success = inside_all[rows, last] & committed
        outside = valid & ~inside_all
        last_out = np.where(outside.any(1), T - 1 - np.argmax(outside[:, ::-1], axis=1), -1)
        settle = (last_out + 1) * cfg.dt_s
        time_s = np.where(success, np.maximum(settle, cfg.dt_s), last * cfg.dt_s)
    hand_valid = valid.T & np.isfinite(hand_tm[..., 0])  # time-major
    return ModeResult(
        success=success,
        time_s=time_s,
        cosine_mean=cos.mean,
        cosine_sum=cos.total,
        agreement=ag.ratio,
        n_actions=cos.n_actions,
        final=poses[rows, last],
        hist=metrics.trajectory_histogram(poses_tm[valid.T], HIST_BINS, ranges),
        paths=_paths(poses[:n_paths], lengths[:n_paths]),
        phase_cos=ph_cos,
        phase_agree=ph_ag,
        y_only=cross,
        lengths=lengths,
        gave_up=gave_up,
        n_idle=cos.n_skipped,
        hand_hist=metrics.trajectory_histogram(hand_tm[hand_valid], HIST_BINS, ranges),
        hand_paths=_paths(hand[:n_paths], lengths[:n_paths]),
        variants=_variants(cfg, groups, acted, lit, c),
        committed=committed,
        hand_final=hand[rows, last],
        attempt=np.full(N, attempt, dtype=np.int64),
        history_norm=np.zeros(N) if history_norm is None else history_norm,
        settled=np.zeros(N, dtype=bool) if settled is None else settled,
    )


VARIANTS = {
    "normalised": "actions divided by the velocity limits (metres and radians weigh alike)",
    "translation": "the translation group only (x, y; m/s)",
    "rotation": "the rotation group only (heading; rad/s)",
    "dead_band": (
        "LABELLED VARIANT: the literal definitions, skipping actions where the robot's output "
        "is under 1 mm/s and 1 mrad/s (a parked robot copying a vanishing share of the hand "
        "no longer counts as agreeing)"
    ),
}


def _variants(
    cfg: SimConfig,
    groups: Sequence[metrics.ActionProducts],
    acted: NDArray[np.bool_],
    literal: metrics.ActionProducts,
    literal_cos: Array,
) -> dict[str, Array]:
    """Per-trajectory cosine distance and agreement under the definitions of VARIANTS; each
    is the literal metric on re-weighted dimensions or a narrower set of actions. `groups`:
    the actions' products of the translation and of the rotation group."""
    trans, rot = groups
    # Divided by the velocity limits: one limit per group (v_max_mps, w_max_radps).
    a = cfg.arbitration
    norm = metrics.ActionProducts.combine(
        groups, (1.0 / (a.v_max_mps * a.v_max_mps), 1.0 / (a.w_max_radps * a.w_max_radps))
    )
    # The output under 1 mm/s and 1 mrad/s (the planar robot turns about z only).
    still = (trans.oo < DEAD_BAND_MPS**2) & (rot.oo < DEAD_BAND_MPS**2)
    out: dict[str, Array] = {}
    for name, p, c, mask in (
        ("normalised", norm, None, acted),
        ("translation", trans, None, acted),
        ("rotation", rot, None, acted),
        ("dead_band", literal, literal_cos, acted & ~still),
    ):
        cos = metrics.cosine_distances(p) if c is None else c
        out[f"{name}.cosine_distance"] = metrics.summarise_cosines(cos, mask).mean
        out[f"{name}.agreement"] = metrics.agreement_of(p, mask).ratio
    return out


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
        raise ContractError("chunks do not cover the trajectories exactly once")

    modes = {m.value: concat_results([c.modes[m.value] for c in ordered]) for m in cfg.modes}
    return StudyResult(
        config=cfg,
        lengths=np.concatenate([c.lengths for c in ordered]),
        lead=np.concatenate([c.lead for c in ordered]),
        operator_hist=np.sum([c.operator_hist for c in ordered], axis=0),
        operator_paths=_cat_paths([c.operator_paths for c in ordered]),
        modes=modes,
    )


FIGURE_OPERATOR: OperatorKind = "side"
FIGURE_MODES: tuple[Mode, ...] = (Mode.S, Mode.DS)


def figure_study(cfg: SimConfig) -> SimConfig:
    """The study behind Fig. 5/6 and the x-per-y remark: as in the paper, an operator who
    does not watch the robot. `cfg` itself when its operator is open loop; otherwise the
    paper's scenario (the `side` operator), S and DS, on the first `max_paths` trajectories
    (the ones Fig. 5b draws; more if the example is beyond them) with the same seed."""
    if not cfg.closed_loop:
        return cfg
    wanted = max(cfg.max_paths, 1 if cfg.example is None else cfg.example + 1)
    n = min(cfg.trajectories, wanted)
    return dataclasses.replace(cfg, operator=FIGURE_OPERATOR, modes=FIGURE_MODES, trajectories=n)


def fig5_remark(res: StudyResult) -> dict[str, Any]:
    """The paper's Fig. 5 remark, measured: while the operator moves along y only, how much
    x the output adds per unit of y (sum |U_out,x| / sum |U_out,y| per trajectory), S vs DS,
    with the paired test (S minus DS)."""
    cfg = res.config
    out: dict[str, Any] = {
        "operator": cfg.operator,
        "trajectories": cfg.trajectories,
        "claim": (
            "paper Fig. 5/6: while the operator moves along y, S forces motion along x and DS "
            "keeps alpha_x low"
        ),
    }
    for name in ("S", "DS"):
        if name in res.modes:
            r = res.modes[name]
            out[name] = {
                "pooled": _safe_ratio(r.y_only[:, 0].sum(), r.y_only[:, 1].sum()),
                **_mean_ci(x_per_y(r)),
            }
    if "S" in res.modes and "DS" in res.modes:
        a, b = x_per_y(res.modes["S"]), x_per_y(res.modes["DS"])
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() >= 2:
            out["paired_t_S_minus_DS"] = dataclasses.asdict(metrics.paired_t_test(a[ok], b[ok]))
    return out


def summarise(res: StudyResult, figures: StudyResult | None = None) -> dict[str, Any]:
    """The summary.json object: per mode metrics, S vs DS tests, divergences, config, and
    the Fig. 5 remark from `figures` (the open-loop companion, `figure_study`; `res` itself
    when None)."""
    cfg = res.config
    modes: dict[str, Any] = {}
    for name, r in res.modes.items():
        sr = metrics.success_rate(int(r.success.sum()), int(r.success.size))
        modes[name] = {
            "n": int(r.success.size),
            "success_rate": {
                "estimate": sr.laplace,
                "ci95": [sr.ci_low, sr.ci_high],
                "successes": sr.successes,
                "n": sr.n,
            },
            "time_s": {**geometric(r.time_s), "censored": censoring(cfg, r)},
            "cosine_distance": {
                "definition": COSINE_DEFINITION,
                **geometric(r.cosine_sum),
                "per_action_mean": {"label": PER_ACTION_LABEL, **_mean_ci(r.cosine_mean)},
                "actions": int(r.n_actions.sum()),
                "skipped_idle": int(r.n_idle.sum()),
            },
            "agreement": {**geometric(r.agreement), "skipped_idle": int(r.n_idle.sum())},
            "by_phase": {
                "edges": PHASE_EDGES.tolist(),
                "cosine_distance": _ratio(*r.phase_cos.sum(0)),
                "agreement": _ratio(*r.phase_agree.sum(0)),
            },
            "x_per_y_while_operator_moves_y_only": {
                "pooled": _safe_ratio(r.y_only[:, 0].sum(), r.y_only[:, 1].sum()),
                **_mean_ci(x_per_y(r)),
            },
            "gave_up_share": float(r.gave_up.mean()),
            "committed_share": float(r.committed.mean()),
            "runs": [_run_summary(r, r.attempt == a) for a in range(cfg.runs)],
            "metric_variants": _metric_variants(r),
        }
    out: dict[str, Any] = {
        "schema": SCHEMA,
        "seed": cfg.seed,
        "trajectories": cfg.trajectories,
        "runs": cfg.runs,
        "modes": modes,
        "tests": {},
        "divergence": fig8_divergences(
            {k: v.hand_hist for k, v in res.modes.items()},
            {k: v.hist for k, v in res.modes.items()},
        ),
        "operator": {
            "kind": cfg.operator,
            "closed_loop": cfg.closed_loop,
            "lead_share": float(res.lead.mean()),
            "trial_s": {
                name: _describe(np.asarray((r.lengths - 1) * cfg.dt_s, dtype=np.float64))
                for name, r in res.modes.items()
            },
        },
        "config": cfg.to_dict(),
        "fig5_fig6": fig5_remark(figures or res),
    }
    if "S" in res.modes and "DS" in res.modes:
        out["tests"]["S_vs_DS"] = compare(res.modes["S"], res.modes["DS"])
    if "scalar" in res.modes and "DS" in res.modes:
        # The tuned baseline with the same levers (docs/tuned/README.md) against DS.
        out["tests"]["scalar_vs_DS"] = compare(res.modes["scalar"], res.modes["DS"])
    if cfg.grasps is not None and cfg.closed_loop:
        out["disagreement"] = disagreement_summary(res)
    return out


def disagreement_summary(res: StudyResult) -> dict[str, Any]:
    """The disagreement world's outcomes, apart for the people who prefer the robot's grasp
    (they agree with it) and those who prefer the other (they disagree in the heading): per
    mode each group's success, time, give-ups, the share that switched to the robot's grasp,
    and which grasp the settled pose is in."""
    cfg = res.config
    g = cfg.grasps
    assert g is not None
    trials = [sample_closed_trial(cfg, n) for n in range(cfg.trajectories)]
    prefers = np.repeat(np.array([t.grasp for t in trials]), cfg.runs)
    robot = g.robot_index
    names = ("top", "side")
    groups = {"prefers_robot_grasp": prefers == robot, "prefers_other_grasp": prefers != robot}
    out: dict[str, Any] = {
        "grasps": g.to_dict(),
        "robot_grasp": g.robot_grasp,
        "people": {k: int(v.sum() // cfg.runs) for k, v in groups.items()},
        "modes": {},
    }
    for name, r in res.modes.items():
        final_grasp = grasp_of(cfg, r.final[:, 2])
        inside = in_success_region(
            r.final[:, :2], r.final[:, 2], cfg.handle_xy_m, cfg.grasp_headings,
            cfg.success_radius_m, cfg.success_heading_rad,
        )  # fmt: skip
        per: dict[str, Any] = {}
        for key, rows in groups.items():
            n = int(rows.sum())
            sr = metrics.success_rate(int(r.success[rows].sum()), n)
            ok = r.success[rows]
            per[key] = {
                "n": n,
                "success_rate": {"estimate": sr.laplace, "ci95": [sr.ci_low, sr.ci_high]},
                "time_s": metrics.geometric_mean(r.time_s[rows]).mean if n else None,
                "gave_up_share": float(r.gave_up[rows].mean()) if n else None,
                "switched_share": float(r.settled[rows].mean()) if n else None,
                "successes_in": {
                    names[k]: int((ok & (final_grasp[rows] == k)).sum()) for k in range(2)
                },
                "settled_in_a_grasp_share": float(inside[rows].mean()) if n else None,
            }
        out["modes"][name] = per
    return out


def _run_summary(r: ModeResult, rows: NDArray[np.bool_]) -> dict[str, float]:
    """One run's success (Laplace), time (geometric mean), shares and history term."""
    sr = metrics.success_rate(int(r.success[rows].sum()), int(rows.sum()))
    return {
        "n": int(rows.sum()),
        "success_rate": sr.laplace,
        "time_s": metrics.geometric_mean(r.time_s[rows]).mean,
        "committed_share": float(r.committed[rows].mean()),
        "gave_up_share": float(r.gave_up[rows].mean()),
        "history_term_l1": float(r.history_norm[rows].mean()),
    }


COSINE_DEFINITION = (
    "the paper's: per trajectory, the SUM over its actions of 1 - U_h.U_out / (|U_h||U_out|), "
    "idle actions (|U_h| or |U_out| <= 1e-9) skipped; over trajectories its geometric mean"
)
PER_ACTION_LABEL = (
    "LABELLED VARIANT: per trajectory the mean per counted action (the sum divided by the "
    "actions), mean over trajectories; not the paper's definition"
)


def geometric(x: Array) -> dict[str, Any]:
    """Over trajectories, as the paper's Table I: the geometric mean of positive values with
    the 95 % interval of the log mean (None when a value is <= 0: `nonpositive` counts them),
    and beside it, labelled, the arithmetic mean with its t interval."""
    x = x[np.isfinite(x)]
    nonpositive = int(np.count_nonzero(x <= 0))
    gm = metrics.geometric_mean(x) if x.size and nonpositive == 0 else None
    ar = _mean_ci(x)
    return {
        "geometric_mean": None if gm is None else gm.mean,
        "ci95": [None, None] if gm is None else [gm.ci_low, gm.ci_high],
        "n": int(x.size),
        "nonpositive": nonpositive,
        "arithmetic_mean": ar["mean"],
        "arithmetic_ci95": ar["ci95"],
    }


def censored(cfg: SimConfig, r: ModeResult) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per trajectory, whether its time is censored: (gave up, ran to the limit). Closed
    loop: the operator gave up (its patience), or the trial ran to `max_trial_s`; open loop:
    a failed trial, whose time is the trial's end rather than a settling time."""
    if not cfg.closed_loop:
        return np.zeros_like(r.success), ~r.success
    limit = round(cfg.max_trial_s / cfg.dt_s) + 1
    return r.gave_up.copy(), (r.lengths >= limit) & ~r.gave_up


def censoring(cfg: SimConfig, r: ModeResult) -> dict[str, Any]:
    """Counts and share of the censored times of one mode (`censored`)."""
    gave_up, limit = censored(cfg, r)
    n = int(r.success.size)
    count = int(np.count_nonzero(gave_up | limit))
    return {
        "count": count,
        "share": count / n if n else None,
        "gave_up": int(gave_up.sum()),
        "time_limit": int(limit.sum()),
        "about": (
            "the operator gave up (patience) or the trial ran to the time limit: the time is a "
            "lower bound"
            if cfg.closed_loop
            else "open loop: a failed trial never settled; its time is the trial's end"
        ),
    }


#: The paper's Fig. 8 divergences (its human study; x, y, z positions), for reference.
PAPER_FIG8 = {
    "operator_DS~operator_S": 0.1293,
    "robot_DS~robot_S": 0.1896,
    "operator_DS~robot_DS": 0.2905,
    "operator_S~robot_S": 0.3017,
}


def fig8_divergences(
    operator: dict[str, NDArray[np.int64]], robot: dict[str, NDArray[np.int64]]
) -> dict[str, Any]:
    """Jensen-Shannon divergences (base 2) of Fig. 8's pairs of trajectory histograms, each
    mode's own: the operator (hand) under DS vs under S, the robot under DS vs under S, and
    the operator vs the robot of every mode. Pairs with an empty histogram are left out.

    Args:
        operator: per mode, the histogram of the operator's hand over that mode's trials.
        robot: per mode, the robot's histogram (same bins).
    """

    def jsd(a: NDArray[np.int64], b: NDArray[np.int64]) -> float | None:
        return metrics.js_divergence(a, b) if a.sum() > 0 and b.sum() > 0 else None

    pairs: dict[str, float | None] = {}
    if "S" in operator and "DS" in operator:
        pairs["operator_DS~operator_S"] = jsd(operator["DS"], operator["S"])
        pairs["robot_DS~robot_S"] = jsd(robot["DS"], robot["S"])
    per_mode = {m: jsd(operator[m], robot[m]) for m in operator}
    for m in ("DS", "S"):
        if m in per_mode:
            pairs[f"operator_{m}~robot_{m}"] = per_mode[m]
    return {
        "about": (
            "Fig. 8: Jensen-Shannon divergence (base 2, in [0, 1]) between histograms of "
            "trajectory points, each of the operator or the robot under one mode"
        ),
        "fig8": pairs,
        "operator_vs_robot": per_mode,
        "paper_fig8": PAPER_FIG8,
    }


def headline(r: ModeResult) -> dict[str, float]:
    """The headline numbers of one mode over its trajectories, flat (for tuning and tables).

    Keys: `success` (Laplace estimate) with `successes`, `n` and its adjusted-Wald interval
    `success_ci_low`/`_high`; `agreement` and `cosine_distance` (means over trajectories, nan
    without any) with the half-widths of their 95 % t intervals (`*_ci_half`); `time_s` (the
    geometric mean [s]) and `gave_up` (the share of trials the operator gave up).
    """
    sr = metrics.success_rate(int(r.success.sum()), int(r.success.size))
    out: dict[str, float] = {
        "success": sr.laplace,
        "successes": float(sr.successes),
        "n": float(sr.n),
        "success_ci_low": sr.ci_low,
        "success_ci_high": sr.ci_high,
    }
    for name, x in (("agreement", r.agreement), ("cosine_distance", r.cosine_mean)):
        m = _mean_ci(x)
        lo, hi = m["ci95"]
        out[name] = math.nan if m["mean"] is None else float(m["mean"])
        out[f"{name}_ci_half"] = math.nan if lo is None else float(hi - lo) / 2.0
    out["time_s"] = metrics.geometric_mean(r.time_s).mean
    out["gave_up"] = float(r.gave_up.mean())
    return out


def _metric_variants(r: ModeResult) -> dict[str, Any]:
    """`metric_variants` of one mode: the headline definitions and the others (see
    `_variants`), each the mean over trajectories with its 95 % interval."""
    out: dict[str, Any] = {
        "literal": {
            "about": "the paper's definitions on U in m/s and rad/s (the headline numbers)",
            "cosine_distance": _mean_ci(r.cosine_mean),
            "agreement": _mean_ci(r.agreement),
        }
    }
    for name, about in VARIANTS.items():
        out[name] = {
            "about": about,
            "cosine_distance": _mean_ci(r.variants[f"{name}.cosine_distance"]),
            "agreement": _mean_ci(r.variants[f"{name}.agreement"]),
        }
    out["fingers"] = {
        "about": "the planar study has no fingers",
        "cosine_distance": None,
        "agreement": None,
    }
    out["by_phase"] = {
        "about": "pooled over trajectories per decile of each trial's duration",
        "edges": PHASE_EDGES.tolist(),
        "cosine_distance": _ratio(*r.phase_cos.sum(0)),
        "agreement": _ratio(*r.phase_agree.sum(0)),
    }
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
        "success_mcnemar": dataclasses.asdict(metrics.mcnemar(a.success, b.success)),
        "log_time": {
            "two_sample_t": dataclasses.asdict(metrics.log_t_test(a.time_s, b.time_s)),
            "paired_t": dataclasses.asdict(
                metrics.paired_t_test(np.log(a.time_s), np.log(b.time_s))
            ),
        },
        "cosine_distance": both(a.cosine_sum, b.cosine_sum),
        "cosine_distance_per_action_mean": both(a.cosine_mean, b.cosine_mean),
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
