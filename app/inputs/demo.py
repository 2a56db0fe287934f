"""The built-in demo: a simulated person doing the pick-and-place task through the camera.

The person is the closed-loop operator of the study (`dsteleop.app.operator.closed_loop`), in
6-D with the robot's fingers: it watches the robot (the loop's records, with its perception
delay) and moves its hand, in submovements, to bring the robot's palm through its own plan
towards the TRUE goals (the robot only knows noisy ones):

    open      open the hand where it is (only after a failed grasp: see below)
    approach  open hand `approach_m` above the grasp pose, along the handle: a person
              reaching for a spoon standing in a holder brings the hand above the grip and
              lowers it onto it (arriving at grasp height off-centre, the finger roots land
              on the grip's top edge, and push or twist the utensil in its holder)
    pick      open hand at the utensil's grasp pose (lowered onto the grip)
    grasp     close the fingers there (a finger movement: the palm is not steered)
    carry     closed hand at the place pose above the bin
    release   open the fingers
    withdraw  open hand a little above the place pose (the utensil slides off the fingers);
              satisfied, it holds still

A stage the robot has already reached by itself is skipped, and a person who sees the robot
grasp the utensil by itself (the task's grasp event while it still reaches for it) moves on
to the carry.

A person whose grasp failed (the hand closed at the utensil, but the utensil stayed in its
holder) opens the hand and tries again: the retry starts with the `open` stage, which only
an open hand satisfies. (Starting it at `pick` would not do: the closed hand at the grasp
pose already satisfies `grasp`, so the stage-skipping would jump straight to `carry`, and the
retry would fire again on the next tick, forever, with the hand never opening.)

The person looks at the utensil, not at where it stood: until it holds the utensil, its
approach and grasp poses follow the utensil's current pose (a hand that brushed it may have
pushed or twisted it in its holder).

When the task resets (`X_reset` in a record: after an outcome, or a reset from the page) it
starts over from the robot's new pose with a fresh plan.

The person wants the task's utensil (`Task.true_goals`): the one the robot is told, or with a
robot that infers its goal (`--goal infer`) the one `--utensil` names. It may change its mind
(`DemoConfig.change_to`, `--change-mind UTENSIL:S`): `change_at_s` seconds into each trial,
while it still reaches (it holds no utensil yet), it wants `change_to` instead, and
redirects its hand at once: the submovement under way is dropped where the hand is, and the
next is planned from there towards the new utensil (a fresh attempt, as after a failed
grasp). People redirect a reach within a reaction time of the new target, without finishing
the first movement (the double-step experiments: Georgopoulos, Kalaska & Massey 1981; Flash &
Henis 1991), so `change_at_s` is when the redirect starts, the reaction included. (The
study's people change theirs from their next plan, `closed_loop.Intention.change_at_s`: a
planar reach of one submovement.) A robot told the first utensil would then work against it,
so the command line allows it only with `--goal infer`.

The person works in the operator's world (`DemoConfig.world`, `Impairments`, docs/operator.md):
it perceives the robot through the demo's one virtual camera (its viewing axis is the base's
x axis: depth misjudged more than lateral position) and through the link's image delay; the
command delay is the loop's `input_delay_s` and the goal noise the task's (both set from the
same world by `app/compose/root.py`), so each impairment is one mechanism.

The hand reaches the tracking pipeline as landmarks of the kinematic hand model
(`tracking.synthetic.SyntheticSource`) in a virtual camera: the operator's robot-frame pose is
converted to the camera frame through a fixed `WorkspaceMapping` anchored where the demo's
camera sees the hand at the robot's start pose. The loop cannot tell it from a person.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.operator.closed_loop import ClosedLoopOperator
from dsteleop.app.operator.person import Intention, OperatorProfile
from dsteleop.app.operator.world import Impairments
from dsteleop.app.session.schema import TickRecord
from dsteleop.arbitration import ArbitrationConfig, HandState
from dsteleop.arbitration.se3 import stack as stack_states
from dsteleop.errors import ConfigError
from dsteleop.robot.task import EventKind, Phase
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping, human_openness
from dsteleop.tracking.synthetic import LandmarkNoise, SyntheticSource, palm_facing_camera

Array = NDArray[np.float64]

#: Where the virtual camera sees the hand when the robot is at its start pose [m, camera
#: frame]: right of and above the image centre, so the whole pick-and-place (the robot moves
#: 0.56 m to the left and 0.2 m down, 1.5x the hand) stays in view.
HAND_ANCHOR_CAM_M = (0.18, -0.06, 0.6)

STAGES = ("open", "approach", "pick", "grasp", "carry", "release", "withdraw")
#: The stage a first attempt starts at (the hand starts open: nothing to open).
FIRST_STAGE = STAGES.index("approach")


@dataclass(frozen=True)
class DemoConfig:
    """The demo person's plan (the person itself is `OperatorProfile`).

    Attributes:
        seed: seed of every random draw of the operator (each episode its own stream).
        grasp_tolerance_m: it closes its hand when the robot's palm is this close to the
            grasp pose [m] (the task's own closing radius, `TaskConfig.close_radius_m`: a
            person who knows the task aims as close as the robot is asked to) ...
        grasp_tolerance_rad: ... and this close in orientation [rad] (`close_radius_rad`).
        tolerance_m: it is satisfied when the robot's palm is this close to the other
            stages [m] ...
        tolerance_rad: ... and this close in orientation [rad].
        tolerance_openness: ... and the fingers this close (fingers closed on a utensil
            stop at contact, around openness 0.3).
        approach_m: how far above the grasp pose (along the handle) the hand comes before it
            is lowered onto the grip [m]: the open fingers reach 9 cm below the palm, so
            5 cm above the grasp pose they already straddle the grip while the finger roots
            are well clear of its top.
        withdraw_m: how far the hand withdraws upwards after the release [m].
        closed_openness: finger openness of a closed hand.
        patience_s: it gives up after this long in one episode without finishing [s].
        retry_after_s: it tries again when the task is not over this long after it was
            satisfied [s] (observe).
        speed_share: its hand's peak speeds, as a share of the robot's velocity limits. The
            camera adds jitter to the hand's measured speed (a still hand in the demo camera:
            p95 71 mm/s, 0.36 rad/s, 1.0 /s, i.e. 25-36 % of the limits; docs/METHOD.md §4),
            and U_human saturates at the limits, so a hand moving at the limits would lose
            motion: 0.6 leaves that headroom.
        fps: camera frame rate [Hz].
        world: the impairments the demo runs under (docs/operator.md): by default the
            study's, from the literature; `describe()` says which, in one line.
        change_to: the utensil it turns to when it changes its mind (module docstring), or
            None: it keeps its utensil.
        change_at_s: when, from the start of each trial [s] (> 0).
    """

    seed: int = 0
    grasp_tolerance_m: float = 0.01
    grasp_tolerance_rad: float = 0.1
    tolerance_m: float = 0.015
    tolerance_rad: float = 0.15
    tolerance_openness: float = 0.4
    approach_m: float = 0.05
    withdraw_m: float = 0.08
    closed_openness: float = 0.0
    patience_s: float = 90.0
    retry_after_s: float = 2.0
    speed_share: float = 0.6
    fps: float = 30.0
    world: Impairments = field(default_factory=Impairments)
    change_to: str | None = None
    change_at_s: float = 1.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.change_at_s) and self.change_at_s > 0):
            raise ConfigError(f"demo: change_at_s must be > 0 seconds, got {self.change_at_s!r}")

    def describe(self) -> str:
        """The demo's world in one line (for the page's status)."""
        change = (
            ""
            if self.change_to is None
            else f"; the person turns to the {self.change_to} after {self.change_at_s:g} s"
        )
        return f"demo world: {self.world.describe()}{change}"


def demo_intention(
    pick: HandState, place: HandState, config: DemoConfig
) -> tuple[HandState, Array, Array]:
    """The stages' robot poses (S,), tolerances (S, 3) and masks (S, D) of `STAGES`."""
    F = pick.n_fingers
    opened, closed = np.ones(F), np.full(F, config.closed_openness)
    above = pick.position - config.approach_m * pick.rotation[:, 2]  # palm z: down the handle
    poses = [
        HandState(pick.position, pick.rotation, opened),  # open: fingers only (mask)
        HandState(above, pick.rotation, opened),
        HandState(pick.position, pick.rotation, opened),
        HandState(pick.position, pick.rotation, closed),
        HandState(place.position, place.rotation, closed),
        HandState(place.position, place.rotation, opened),
        HandState(place.position + np.array([0.0, 0.0, config.withdraw_m]), place.rotation, opened),
    ]
    S = len(poses)
    tol = np.tile((config.tolerance_m, config.tolerance_rad, config.tolerance_openness), (S, 1))
    tol[STAGES.index("pick"), :2] = (config.grasp_tolerance_m, config.grasp_tolerance_rad)
    tol[STAGES.index("withdraw"), :2] = (2 * config.tolerance_m, 2 * config.tolerance_rad)
    # Opening and closing the hand are finger movements: the palm is not steered meanwhile.
    mask = np.ones((S, 6 + F))
    mask[[STAGES.index("open"), STAGES.index("grasp"), STAGES.index("release")], :6] = 0.0
    return stack_states(poses), tol, mask


class DemoOperator:
    """The demo person (module docstring): a `ClosedLoopOperator` of one. Thread-safe: the
    camera thread asks for the hand, the loop thread reports the robot.

    Args:
        true_goals: returns the true (pick, place) palm poses in the base frame, the pick of
            the utensil it is given (None: the task's).
        start: the robot's start state (the hand starts there, open).
        config: the demo person's plan.
        profile: the person (default: `OperatorProfile()` capped at the robot's limits).
    """

    def __init__(
        self,
        true_goals: Callable[[str | None], tuple[HandState, HandState]],
        start: HandState,
        config: DemoConfig | None = None,
        profile: OperatorProfile | None = None,
        arbitration: ArbitrationConfig | None = None,
    ) -> None:
        self.config = config or DemoConfig()
        a = arbitration or ArbitrationConfig()
        base = profile or OperatorProfile(patience_s=self.config.patience_s)
        self.profile = base.for_robot(
            a.v_max_mps, a.w_max_radps, a.g_max_per_s, self.config.speed_share
        )
        self._true_goals = true_goals
        self._lock = threading.Lock()
        self._episode = 0
        self._attempt = 0
        self._first = FIRST_STAGE  # the stage the current attempt started at
        self._done_since: float | None = None
        self._t = 0.0  # the latest source time the hand was asked for
        self._seen = False
        self._holding = False  # the utensil is in the hand (a grasp event, no release since)
        self._t_episode = 0.0  # when the current episode started (source time) [s]
        self._wanted: str | None = None  # the utensil it wants (None: the task's)
        opened = HandState(start.position, start.rotation, np.ones(start.n_fingers))
        self._op = self._person(opened, 0.0, FIRST_STAGE)
        self.dt = 1.0 / self.config.fps

    def _intention(self, first: int) -> Intention:
        """The plan from stage `first` of STAGES on, to the true goals as they are now."""
        pick, place = self._true_goals(self._wanted)
        targets, tol, mask = demo_intention(pick, place, self.config)
        S = len(STAGES) - first
        plan = HandState(
            targets.position[first:], targets.rotation[first:], targets.openness[first:]
        )
        return Intention(
            _one(plan), tol[None, first:], mask[None, first:], np.array([S]), np.array([0.3])
        )

    def _person(self, hand: HandState, t0_s: float, first: int) -> ClosedLoopOperator:
        """A fresh attempt from `hand`, at stage `first` of STAGES."""
        intention = self._intention(first)
        rng = np.random.default_rng([self.config.seed, self._episode, self._attempt])
        self._first, self._done_since = first, None
        return ClosedLoopOperator(
            intention, _one(hand), self.profile, [rng], t0_s, world=self.config.world
        )

    @property
    def wanted(self) -> str | None:
        """The utensil it wants now when it changed its mind, else None (the task's)."""
        return self._wanted

    @property
    def stage(self) -> str:
        """The stage the person works on (`done` when satisfied, `gave up` after patience)."""
        with self._lock:
            if bool(self._op.gave_up[0]):
                return "gave up"
            if bool(self._op.done[0]):
                return "done"
            return STAGES[self._first + int(self._op.stage[0])]

    def observe(self, record: TickRecord) -> None:
        """See the robot and the task (the loop calls this with every tick's record).

        A task reset starts a new episode from the robot's new pose. Within an episode the
        person also sees the utensil (the task's `grasp` and `release` events stand for what
        it sees): it tries again when the utensil is not where its plan has it, from where
        the task is:

            the robot grasped the utensil by itself while the person was still reaching for
                it: it goes on to carry (its plan's next stages wait for an open hand)
            the hand is closed, but the utensil stayed in its holder (no grasp), and the
                person has gone on to carry: open the hand and pick again (stage `open`)
            the utensil left the hand before the person released it (a `release` event while
                it picks or carries): open the hand and pick again
            the task is not over `retry_after_s` after the person was satisfied: pick again
                if the utensil is not in the hand, carry again if it still is
        """
        if record.X_reset is not None and self._seen:  # not the loop's very first tick
            self.restart(record.X_reset)
        phase = record.plant.phase
        with self._lock:
            op = self._op
            op.observe(self._t, _one(record.X_current))
            self._seen = True
            stage = self._first + int(op.stage[0])
            dropped = grasped_for_me = False
            for e in record.plant.events:
                if e.kind is EventKind.GRASP:
                    self._holding = True
                    grasped_for_me = stage < STAGES.index("grasp")
                elif e.kind is EventKind.RELEASE:
                    dropped = self._holding and stage < STAGES.index("release")
                    self._holding = False
            if phase is Phase.DONE:
                return
            change = self.config.change_to
            if (
                change is not None
                and self._wanted != change
                and not self._holding
                and phase is Phase.PICK
                and self._t - self._t_episode >= self.config.change_at_s
            ):
                # Its mind changed: the movement under way is dropped where the hand is, and
                # a fresh attempt plans towards the new utensil (module docstring).
                self._wanted = change
                self._attempt += 1
                H = op.current
                hand = HandState(H.position[0], H.rotation[0], H.openness[0])
                self._op = self._person(hand, self._t, self._first)
                self._op.observe(self._t, _one(record.X_current))
                return
            if (phase is Phase.PICK or not self._holding) and self._first < STAGES.index("carry"):
                # It looks at the utensil, not at where it stood: a hand that brushed it on
                # the way may have pushed or twisted it in its holder.
                self._op.intention = self._intention(self._first)
            retry: int | None = None
            regrasp = STAGES.index("open")
            if grasped_for_me:
                retry = STAGES.index("carry")
            elif not op.done[0] and (
                dropped or (phase is Phase.PICK and stage >= STAGES.index("carry"))
            ):
                retry = regrasp
            elif op.done[0]:
                if self._done_since is None:
                    self._done_since = self._t
                elif self._t - self._done_since >= self.config.retry_after_s:
                    empty = phase is Phase.PICK or not self._holding
                    retry = regrasp if empty else STAGES.index("carry")
            if retry is not None:
                self._attempt += 1
                H = op.current
                self._op = self._person(
                    HandState(H.position[0], H.rotation[0], H.openness[0]), self._t, retry
                )

    def restart(self, start: HandState) -> None:
        """Start over from `start` (a new episode: a fresh plan and random stream)."""
        with self._lock:
            self._episode += 1
            self._attempt = 0
            self._holding = False
            self._t_episode = self._t
            self._wanted = None
            opened = HandState(start.position, start.rotation, np.ones(start.n_fingers))
            self._op = self._person(opened, self._t, FIRST_STAGE)

    def hand_at(self, t_s: float) -> HandState:
        """The person's hand (base frame, robot fingers) at source time `t_s`."""
        with self._lock:
            self._t = max(self._t, float(t_s))
            H = self._op.hand(self._t)
            return HandState(H.position[0], H.rotation[0], H.openness[0])


def _one(X: HandState) -> HandState:
    """A batch of one."""
    return HandState(X.position[None], X.rotation[None], X.openness[None])


class DemoCamera:
    """Converts the operator's base-frame hand into the virtual camera's frame."""

    def __init__(self, start: HandState, mapping: MappingConfig | None = None) -> None:
        self.mapping = WorkspaceMapping(mapping or MappingConfig())
        self.mapping.anchor_at(np.array(HAND_ANCHOR_CAM_M), palm_facing_camera(), start)

    def trajectory(self, operator: DemoOperator) -> Callable[[float], tuple[HandState, Array]]:
        def at(t_s: float) -> tuple[HandState, Array]:
            X = operator.hand_at(t_s)
            p_cam, R_cam = self.mapping.to_camera(X)
            g5 = human_openness(X.openness, self.mapping.mix)
            return HandState(p_cam, R_cam, g5), g5

        return at


def demo_source(
    operator: DemoOperator, camera: DemoCamera, realtime: bool, seed: int = 0
) -> SyntheticSource:
    """The synthetic camera source that shows the demo operator's hand, with a little
    detector noise (0.5 px on the image landmarks, 1 mm on the world landmarks)."""
    return SyntheticSource(
        camera.trajectory(operator),
        fps=operator.config.fps,
        realtime=realtime,
        seed=seed,
        noise=LandmarkNoise(image_px=0.5, world_m=0.001),
    )
