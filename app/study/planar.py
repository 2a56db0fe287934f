"""The study's planar world and its trials (Section IV-A/B of the paper): pure, no I/O, no clock.

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
                     autonomous) with the same operator and goal noise (paired;
                     `app.study.batch` steps them)

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
stays in the success region to the end (its settling time), or the whole trial on failure
(`app.study.results`).

This module holds the world (`SimConfig`, the success test) and each trajectory's random
part (`sample_trial`, `sample_closed_trial`, `robot_goal`, `closed_operator`); the batched
simulation is `app.study.batch`, the per-trajectory results `app.study.results`, the
summary over trajectories `app.study.summary`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.jsonable import jsonable
from dsteleop.app.operator.closed_loop import ClosedLoopOperator
from dsteleop.app.operator.open_loop import OperatorStrategy, OperatorTrajectory, sample_trajectory
from dsteleop.app.operator.person import Intention, OperatorProfile
from dsteleop.app.operator.world import Impairments
from dsteleop.app.study.grasps import Grasps, settle_after
from dsteleop.app.study.inference import ObjectRuns
from dsteleop.app.study.objects import Objects
from dsteleop.arbitration import ArbitrationConfig, HandState, Mode, registered, so3_exp
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]
OperatorKind = Literal["closed-loop", "side", "aligned", "deviate"]
OPERATORS: tuple[str, ...] = ("closed-loop", "side", "aligned", "deviate")
OPEN_LOOP: tuple[str, ...] = ("side", "aligned", "deviate")


def all_modes(inference: bool = False) -> tuple[Mode, ...]:
    """Every registered mode (`arbitration.modes`), S and DS first: the study's default. In a
    world that tells the robot its goal (`inference` False) but those that read the robot's
    confidence in its goal (`ModeSpec.reads_confidence`: with a told goal they repeat the
    modes they temper; `--modes` runs them); in the objects world, where the robot infers
    its goal, every one."""
    rest = (
        m
        for m in registered()
        if m not in (Mode.S, Mode.DS) and (inference or not m.spec.reads_confidence)
    )
    return (Mode.S, Mode.DS, *rest)


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
        objects: the objects world (`app.study.objects.Objects`: K objects in a row, the
            person wanting one and maybe changing its mind, the robot inferring which from
            the hand and perceiving them with its own error; closed loop only), or None: the
            robot is told its goal.
        mode_arbitration: (mode, its own arbitration) pairs: such a mode runs with its own
            configuration (modes tuned apart that share fields, DS's kappa and DSC's), the
            others with `arbitration`; each must agree with `arbitration` on what the
            simulated people and the belief read (`OPERATOR_FIELDS`, `belief`), so every
            mode meets the same people. Empty: every mode runs with `arbitration`.
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
    objects: Objects | None = None
    mode_arbitration: tuple[tuple[Mode, ArbitrationConfig], ...] = ()

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
        if self.objects is not None:
            if not isinstance(self.objects, Objects):
                raise ConfigError(f"objects must be an Objects, got {self.objects!r}")
            if self.grasps is not None:
                raise ConfigError("the objects world and the disagreement world are apart")
            if not self.closed_loop:
                raise ConfigError("the objects world needs the closed-loop operator")
            self.objects.check(self.success_radius_m, self.operator_tolerance_m)
            if self.objects.count * self.arbitration.belief.epsilon >= 1.0:
                raise ConfigError(
                    f"belief.epsilon must be below 1/K = {1.0 / self.objects.count:.3g} for "
                    f"{self.objects.count} objects, got {self.arbitration.belief.epsilon!r}"
                )
        seen: set[Mode] = set()
        for mode, arb in self.mode_arbitration:
            if not isinstance(mode, Mode) or not isinstance(arb, ArbitrationConfig):
                raise ConfigError(f"mode_arbitration holds (Mode, ArbitrationConfig): {mode!r}")
            if mode in seen:
                raise ConfigError(f"mode_arbitration: {mode.value} given twice")
            seen.add(mode)
            for name in (*OPERATOR_FIELDS, "belief"):
                if getattr(arb, name) != getattr(self.arbitration, name):
                    raise ConfigError(
                        f"{mode.value}'s own configuration differs in {name}, which the "
                        "simulated people or the belief read: every mode must meet the same"
                    )

    def arbitration_of(self, mode: Mode) -> ArbitrationConfig:
        """The arbitration `mode` runs with: its own (`mode_arbitration`) or the study's."""
        return dict(self.mode_arbitration).get(mode, self.arbitration)

    def mode_groups(self) -> list[tuple[ArbitrationConfig, tuple[Mode, ...]]]:
        """The study's modes grouped by the arbitration they run with, in mode order (one
        group, every mode, when no mode has its own)."""
        groups: dict[ArbitrationConfig, list[Mode]] = {}
        for m in self.modes:
            groups.setdefault(self.arbitration_of(m), []).append(m)
        return [(arb, tuple(ms)) for arb, ms in groups.items()]

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
                v = jsonable(self.operator_strategy)
            elif f.name == "profile":
                v = jsonable(self.operator_profile)
            elif f.name in ("grasps", "objects"):
                if v is None:  # the default world's summary stays as it was
                    continue
                v = v.to_dict()
            elif f.name == "mode_arbitration":
                if not v:  # one configuration for every mode: as it was
                    continue
                v = {m.value: a.to_dict() for m, a in v}
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
    cfg: SimConfig,
    trials: Sequence[ClosedTrial],
    attempt: int = 0,
    objects: ObjectRuns | None = None,
) -> ClosedLoopOperator:
    """The operators of `trials`, fresh (each mode starts them from the same state), in run
    `attempt` (each run its own random stream: (seed, n, 1) for run 0, then (seed, n, 1, a)).

    Each wants the robot at the true handle with its own heading within its own tolerance;
    after resistance it settles for the task: the true handle and the normal (in the
    disagreement world: the robot's grasp), within the success radius and heading tolerance
    (the via stage of a y-first person is unchanged), at its first resistance pause (in the
    disagreement world: at its own, `ClosedTrial.settle_after`). In the objects world
    (`objects`: the run's draws of N people, the trials being copies of them, row r of
    person r mod N) the handle is the object the person wants, and a person who changes its
    mind wants the other one, and settles for it, from its change on."""
    N = len(trials)
    sx, sy = cfg.start_xy_m
    h0 = cfg.start_heading
    heading = np.array([t.operator_goal[2] for t in trials])
    lead = np.array([t.lead for t in trials])
    where = np.stack([t.operator_goal[:2] for t in trials])
    person = np.arange(N) % (1 if objects is None else objects.wanted.size)
    if objects is not None:  # the object each wants
        where = objects.true_xy[objects.wanted[person]]
    targets, task = _stage_poses(cfg, where, heading, lead)
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
    accept = (cfg.success_radius_m, cfg.success_heading_rad, 1.0)
    task_tolerance = np.stack(
        [np.where(lead[:, None], passing, accept), np.broadcast_to(accept, (N, 3))], 1
    )
    change_at = change_targets = change_settle = None
    if objects is not None and objects.changes.any():
        change_at = objects.change_at_s[person]
        then = objects.true_xy[objects.final[person]]
        change_targets, change_settle = _stage_poses(cfg, then, heading, lead)
    intention = Intention(
        targets, tolerance, mask, np.where(lead, 2, 1).astype(np.int64),
        np.array([t.turn_within_m for t in trials]), task, task_tolerance,
        None if cfg.grasps is None else np.array([t.settle_after for t in trials]),
        change_at, change_targets, change_settle,
    )  # fmt: skip
    start = planar_state(np.full(N, sx), np.full(N, sy), np.full(N, h0))
    rngs = [np.random.default_rng(t.seed if attempt == 0 else (*t.seed, attempt)) for t in trials]
    return ClosedLoopOperator(intention, start, cfg.operator_profile, rngs, world=cfg.world)


def _stage_poses(
    cfg: SimConfig, xy: Array, heading: Array, lead: NDArray[np.bool_]
) -> tuple[HandState, HandState]:
    """The two stages (N, 2) of people who want the handle at `xy` (N, 2) with their own
    `heading` (N,): stage 0 along y first (to the handle's y, the start's x and heading)
    when leading, stage 1 the handle; and the task's (the same via, then the handle at the
    robot's grasp heading)."""
    N = xy.shape[0]
    sx, h0 = cfg.start_xy_m[0], cfg.start_heading
    goals = np.concatenate([xy, heading[:, None]], -1)
    via = np.stack([np.full(N, sx), xy[:, 1], np.full(N, h0)], -1)
    first = np.where(lead[:, None], via, goals)
    targets = planar_state(
        np.stack([first[:, 0], goals[:, 0]], 1),
        np.stack([first[:, 1], goals[:, 1]], 1),
        np.stack([first[:, 2], goals[:, 2]], 1),
    )
    task = planar_state(
        np.stack([first[:, 0], xy[:, 0]], 1),
        np.stack([first[:, 1], xy[:, 1]], 1),
        np.stack([first[:, 2], np.full(N, cfg.robot_heading)], 1),
    )
    return targets, task


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


FIGURE_OPERATOR: OperatorKind = "side"
FIGURE_MODES: tuple[Mode, ...] = (Mode.S, Mode.DS)


def figure_study(cfg: SimConfig) -> SimConfig:
    """The study behind Fig. 5/6 and the x-per-y remark: as in the paper, an operator who
    does not watch the robot. `cfg` itself when its operator is open loop; otherwise the
    paper's scenario (the `side` operator), S and DS, on the first `max_paths` trajectories
    (the ones Fig. 5b draws; more if the example is beyond them) with the same seed; in the
    objects world with the one handle of the paper's scenario (an open-loop operator does not
    pick an object)."""
    if not cfg.closed_loop:
        return cfg
    wanted = max(cfg.max_paths, 1 if cfg.example is None else cfg.example + 1)
    n = min(cfg.trajectories, wanted)
    return dataclasses.replace(
        cfg, operator=FIGURE_OPERATOR, modes=FIGURE_MODES, trajectories=n, objects=None
    )
