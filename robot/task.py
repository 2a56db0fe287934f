"""Pick-and-place task logic: goals, phases, events and the outcome (paper Section IV-C).

Pure Python + numpy (no PyBullet): the environment feeds it one `TaskObservation` per tick.

Sequence:
    pick   the goal is the grasp pose of the chosen utensil (as the robot knows it: the true
           pose plus seeded noise). Finger part of the goal: open (1) until the palm first
           comes within `close_radius_m` / `close_radius_rad` of the known pick pose, then
           closed (0), latched. The phase ends with a `grasp` event once the utensil has been
           held for `grasp_hold_ticks` ticks.
    place  the goal is a palm pose above the bin (known with its own noise); `X_start` is
           reset to the palm pose at the grasp. Fingers: closed until the palm first comes
           within `release_radius_m` of the known place pose, then open, latched.
    done   an outcome was decided.

A robot that is not told its utensil (`candidates_true` given: the goal is inferred, `--goal
infer`) knows every utensil in the holder as a candidate (`candidates()`: each one's pose as
it perceives it, drawn from `perception`, and each one's own finger schedule: closed once the
palm came within the closing radius of that candidate), and in the place phase the bin as the
one candidate. The task's utensil is then the one the person grasps: the first utensil held
for `grasp_hold_ticks` ends the pick (its `grasp` event names it) and is judged as above;
before that only the timeout decides (a utensil knocked out of the holder is not the task's).
`utensil` names the person's intended utensil until then (the demo person's; the robot never
reads it), and `intended` keeps it.

Events: `goal` (a goal became active; X_start reset), `grasp`, `release` (a held utensil is
no longer held), `success`, `failure`. Outcome rules, checked every tick once the utensil has
been at rest (moved less than `rest_move_m`) and free of the hand for `rest_ticks` ticks:
centre of mass inside the bin's inner footprint -> success (`in_bin`);
below the table top -> failure (`on_floor`); still in the holder -> no outcome (the operator
may try again); anywhere else -> failure (`on_table`). No outcome after `timeout_s` ->
failure (`timeout`). The run time is the simulated time from the start to the outcome.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState, so3_log
from dsteleop.arbitration.se3 import stack as stack_states
from dsteleop.errors import ConfigError
from dsteleop.robot.perception import PerceptionError
from dsteleop.robot.placement import SHIPPED, Placement

Array = NDArray[np.float64]

#: What a robot not told its utensil is told instead (`--goal infer`, the page's menu).
INFER = "infer"


class Phase(str, enum.Enum):
    """Task phase."""

    PICK = "pick"
    PLACE = "place"
    DONE = "done"


class EventKind(str, enum.Enum):
    """Kinds of task events."""

    GOAL = "goal"
    GRASP = "grasp"
    RELEASE = "release"
    SUCCESS = "success"
    FAILURE = "failure"


@dataclass(frozen=True)
class TaskEvent:
    """Something that happened in the task.

    Attributes:
        kind: what happened.
        t_s: simulated time [s].
        detail: e.g. the goal's name ("pick", "place") or the outcome's reason.
    """

    kind: EventKind
    t_s: float
    detail: str = ""


@dataclass(frozen=True)
class Outcome:
    """How a run ended.

    Attributes:
        success: the utensil rests in the bin.
        reason: "in_bin", "on_table", "on_floor" or "timeout".
        time_s: simulated time from the start of the run to the outcome [s].
        utensil: the utensil's name.
    """

    success: bool
    reason: str
    time_s: float
    utensil: str


@dataclass(frozen=True)
class TaskConfig:
    """Task settings (validated at construction).

    Attributes:
        goal_noise_pos_m: std-dev of the Gaussian noise on each known goal position [m]
            (per axis).
        goal_noise_rot_rad: std-dev of the Gaussian rotation-vector noise on each known goal
            orientation [rad] (per axis).
        timeout_s: a run without outcome after this long fails [s].
        close_radius_m: the pick goal's fingers switch to closed within this distance [m] ...
        close_radius_rad: ... and this orientation error [rad] of the known pick pose.
        release_radius_m: the place goal's fingers switch to open within this distance [m].
        grasp_hold_ticks: ticks the utensil must be held before the place goal activates.
        rest_move_m: a utensil whose centre of mass stayed within this distance of its
            current position [m] ...
        rest_ticks: ... over the last this many ticks, untouched by the hand, is at rest.
    """

    goal_noise_pos_m: float = 0.01
    goal_noise_rot_rad: float = 0.05
    timeout_s: float = 120.0
    close_radius_m: float = 0.01
    close_radius_rad: float = 0.1
    release_radius_m: float = 0.03
    grasp_hold_ticks: int = 5
    rest_move_m: float = 0.005
    rest_ticks: int = 15

    def __post_init__(self) -> None:
        for name in ("goal_noise_pos_m", "goal_noise_rot_rad"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"task config: {name} must be finite and >= 0, got {v!r}")
        for name in (
            "timeout_s",
            "close_radius_m",
            "close_radius_rad",
            "release_radius_m",
            "rest_move_m",
        ):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"task config: {name} must be finite and > 0, got {v!r}")
        for name in ("grasp_hold_ticks", "rest_ticks"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"task config: {name} must be an integer >= 1, got {v!r}")


@dataclass(frozen=True)
class Region:
    """An axis-aligned box in the scene frame [m] (`robot.placement`)."""

    lower_m: tuple[float, float, float]
    upper_m: tuple[float, float, float]

    def contains(self, p_m: Array) -> bool:
        return bool(np.all(p_m >= self.lower_m) and np.all(p_m <= self.upper_m))


@dataclass(frozen=True)
class TaskObservation:
    """What the task needs from the simulation each tick.

    Attributes:
        t_s: simulated time since the reset [s].
        palm: the robot's achieved palm state.
        p_utensil_m: (3,) utensil centre of mass, base frame [m].
        held: the hand holds the utensil (grasp helper engaged, or the thumb and another
            closed finger touch it).
        touching: any robot link touches the utensil.
        holding: the utensil the hand holds, by name, whichever it is (None: none), for a
            task whose utensil is not told (`PickPlaceTask.candidates_true`); `p_utensil_m`,
            `held` and `touching` are then of the task's utensil once one was grasped.
    """

    t_s: float
    palm: HandState
    p_utensil_m: Array
    held: bool
    touching: bool
    holding: str | None = None


@dataclass(frozen=True)
class SceneRegions:
    """Where outcomes are decided, in the scene frame (`robot.placement`).

    Attributes:
        bin_inner: the bin's inner volume (up to well above its rim).
        holder: the holder's volume (utensils resting here have no outcome yet).
        floor_below_z_m: a utensil below this height lies on the floor [m].
        placement: where the scene stands in the base frame (observations come in the base
            frame; the shipped layout's is the identity).
    """

    bin_inner: Region
    holder: Region
    floor_below_z_m: float
    placement: Placement = SHIPPED


@dataclass(frozen=True)
class Candidates:
    """The goals a robot that is not told its goal chooses among (module docstring).

    Attributes:
        names: one per candidate (the utensils', or "bin").
        goals: batch (K,): each one's pose as the robot knows it (noisy) and its finger goal.
        sigma: (K, 6 + F) the robot's perception error sd of each, per dimension
            (`PerceptionError.sigma`).
    """

    names: tuple[str, ...]
    goals: HandState
    sigma: Array


@dataclass
class PickPlaceTask:
    """One pick-and-place run; see the module docstring.

    Args:
        config: task settings.
        utensil: name of the utensil to move.
        pick_true: (p [m], R) true grasp pose of the palm.
        place_true: (p [m], R) true palm pose above the bin.
        regions: outcome regions.
        n_fingers: number of robot fingers.
        seed: seed of the goal noise (same seed, same known goals).
        candidates_true: the robot is not told its utensil: every utensil's true grasp pose
            by name (the candidates, in a fixed order); empty: it is told `utensil`.
        perception: how the robot's known goals are drawn (None: isotropic, the config's
            `goal_noise_pos_m` and `goal_noise_rot_rad`, as a told goal always was).
    """

    config: TaskConfig
    utensil: str
    pick_true: tuple[Array, Array]
    place_true: tuple[Array, Array]
    regions: SceneRegions
    n_fingers: int
    seed: int
    candidates_true: dict[str, tuple[Array, Array]] = field(default_factory=dict)
    perception: PerceptionError | None = None
    phase: Phase = Phase.PICK
    events: list[TaskEvent] = field(default_factory=list)
    outcome: Outcome | None = None
    X_start: HandState | None = None
    t_start_s: float = 0.0
    _closing: bool = False
    _releasing: bool = False
    _held_ticks: int = 0
    _was_held: bool = False
    _rest_ticks: int = 0
    _recent_p: list[Array] = field(default_factory=list)
    _closing_at: set[str] = field(default_factory=set)
    _holding: str | None = None

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        c = self.config
        model = self.perception or PerceptionError.isotropic(
            c.goal_noise_pos_m, c.goal_noise_rot_rad
        )
        self.model = model
        self.intended = self.utensil
        #: Each candidate's pose as the robot knows it (told: none), in a fixed order.
        self.candidates_known: dict[str, tuple[Array, Array]] = {}
        if self.candidates_true:
            for name, pose in self.candidates_true.items():
                self.candidates_known[name] = model.sample(*pose, rng)
            self.pick_known = self.candidates_known.get(self.utensil, self.pick_true)
        else:
            self.pick_known = model.sample(*self.pick_true, rng)
        self.place_known = model.sample(*self.place_true, rng)

    @property
    def told(self) -> bool:
        """The robot is told its utensil (no candidates)."""
        return not self.candidates_true

    # ------------------------------------------------------------------ goals
    def candidates(self) -> Candidates | None:
        """What a robot that is not told its utensil chooses among (module docstring): every
        utensil in the pick phase, the bin in the place phase; None when it is told, or once
        the task is done."""
        if self.told or self.phase == Phase.DONE:
            return None
        F = self.n_fingers
        if self.phase == Phase.PICK:
            names = tuple(self.candidates_known)
            poses = [self.candidates_known[n] for n in names]
            fingers = [0.0 if n in self._closing_at else 1.0 for n in names]
            true = [self.candidates_true[n][0] for n in names]
        else:
            names = ("bin",)
            poses = [self.place_known]
            fingers = [1.0 if self._releasing else 0.0]
            true = [self.place_true[0]]
        goals = stack_states(
            [HandState(p.copy(), R.copy(), np.full(F, g)) for (p, R), g in zip(poses, fingers)]
        )
        # The robot knows its error's statistics where the objects are (it sees them there).
        sigma = np.stack([self.model.sigma(p, F) for p in true])
        return Candidates(names, goals, sigma)

    @property
    def goal(self) -> HandState:
        """The active goal as the robot knows it (noisy pose + scheduled finger openness); a
        robot not told its utensil knows none in the pick phase (`candidates`)."""
        if self.phase == Phase.PICK and not self.told:
            raise ConfigError("the robot is not told its utensil: it chooses among candidates()")
        if self.phase == Phase.PICK:
            g = 0.0 if self._closing else 1.0
            p, R = self.pick_known
        else:
            g = 1.0 if self._releasing else 0.0
            p, R = self.place_known
        return HandState(p.copy(), R.copy(), np.full(self.n_fingers, g))

    @property
    def goal_true(self) -> HandState:
        """The active goal without noise (for analysis; the robot policy must not use it)."""
        g = self.goal
        p, R = self.pick_true if self.phase == Phase.PICK else self.place_true
        return HandState(p.copy(), R.copy(), g.openness)

    def start(self, X_current: HandState, t_s: float) -> None:
        """Begin the run: the pick goal becomes active and X_start is the current state."""
        self.t_start_s = t_s
        self.X_start = X_current
        self.events.append(TaskEvent(EventKind.GOAL, t_s, "pick"))

    # ------------------------------------------------------------------ per tick
    def update(self, obs: TaskObservation) -> list[TaskEvent]:
        """Advance the task by one observation; returns the events of this tick."""
        if self.phase == Phase.DONE:
            return []
        new: list[TaskEvent] = []
        c = self.config
        if self.phase == Phase.PICK and self.told and not self._closing:
            self._closing = self._near(obs.palm, self.pick_known)
        elif self.phase == Phase.PICK:
            for name, pose in self.candidates_known.items():
                if name not in self._closing_at and self._near(obs.palm, pose):
                    self._closing_at.add(name)
        if self.phase == Phase.PLACE and not self._releasing:
            d = float(np.linalg.norm(obs.palm.position - self.place_known[0]))
            self._releasing = d < c.release_radius_m
        held = obs.held
        if not self.told and self.phase == Phase.PICK:
            # Not told: whichever utensil the hand holds, held on for grasp_hold_ticks.
            held = obs.holding is not None
            if obs.holding != self._holding:
                self._held_ticks = 0
            self._holding = obs.holding
        self._held_ticks = self._held_ticks + 1 if held else 0
        if held and not self._was_held:
            self._was_held = True
        elif self._was_held and not held and not obs.touching:
            self._was_held = False
            new.append(TaskEvent(EventKind.RELEASE, obs.t_s))
        if self.phase == Phase.PICK and self._held_ticks >= c.grasp_hold_ticks:
            if not self.told and obs.holding is not None:
                self._take(obs.holding)
            new.append(TaskEvent(EventKind.GRASP, obs.t_s, self.utensil))
            self.phase = Phase.PLACE
            self.X_start = obs.palm
            new.append(TaskEvent(EventKind.GOAL, obs.t_s, "place"))
            if not self.told:
                self._recent_p.clear()  # judged from here on: this utensil's rest window
                self._rest_ticks = 0
                self.events.extend(new)
                return new
        if not self.told and self.phase == Phase.PICK:
            outcome = self._timeout(obs)  # no utensil is the task's before a grasp
        else:
            outcome = self._check_outcome(obs)
        if outcome is not None:
            self.outcome = outcome
            self.phase = Phase.DONE
            kind = EventKind.SUCCESS if outcome.success else EventKind.FAILURE
            new.append(TaskEvent(kind, obs.t_s, outcome.reason))
        self.events.extend(new)
        return new

    def _near(self, palm: HandState, pose: tuple[Array, Array]) -> bool:
        """The palm is within the closing radius (position and orientation) of `pose`."""
        p, R = pose
        d = float(np.linalg.norm(palm.position - p))
        a = float(np.linalg.norm(so3_log(R @ palm.rotation.T)))
        return d < self.config.close_radius_m and a < self.config.close_radius_rad

    def _take(self, name: str) -> None:
        """A robot not told its utensil grasped `name`: it is the task's from now on."""
        self.utensil = name
        self.pick_true = self.candidates_true[name]
        self.pick_known = self.candidates_known[name]
        self._closing = True

    def _timeout(self, obs: TaskObservation) -> Outcome | None:
        if obs.t_s - self.t_start_s >= self.config.timeout_s:
            return Outcome(False, "timeout", obs.t_s - self.t_start_s, self.utensil)
        return None

    def _check_outcome(self, obs: TaskObservation) -> Outcome | None:
        c = self.config
        t_run = obs.t_s - self.t_start_s
        # At rest: untouched, and the centre of mass stayed put over the window. (Displacement
        # rather than velocity: a utensil leaning on a wall may jitter at mm scale for
        # seconds in the simulation.)
        self._recent_p.append(obs.p_utensil_m.copy())
        if len(self._recent_p) > c.rest_ticks:
            self._recent_p.pop(0)
        self._rest_ticks = self._rest_ticks + 1 if not obs.touching else 0
        window = np.asarray(self._recent_p)
        settled = (
            self._rest_ticks >= c.rest_ticks
            and float(np.linalg.norm(window - obs.p_utensil_m, axis=1).max()) < c.rest_move_m
        )
        if settled:
            p = self.regions.placement.to_scene(obs.p_utensil_m)
            if self.regions.bin_inner.contains(p):
                return Outcome(True, "in_bin", t_run, self.utensil)
            if p[2] < self.regions.floor_below_z_m:
                return Outcome(False, "on_floor", t_run, self.utensil)
            if not self.regions.holder.contains(p):
                return Outcome(False, "on_table", t_run, self.utensil)
        if t_run >= c.timeout_s:
            return Outcome(False, "timeout", t_run, self.utensil)
        return None
