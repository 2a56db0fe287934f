"""The built-in demo: a synthetic operator's hand doing the pick-and-place task.

The operator plans in the robot's base frame, like a person watching the robot on a screen:
one goal-directed movement at a time, drawn from the stochastic operator model
(`dsteleop.app.operator.open_loop`, the same model as the simulation study), towards the
TRUE goal of the current stage (the robot only knows noisy goals):

    reach    open hand to the grasp pose of the utensil
    grasp    close the fingers where the hand is
    carry    closed hand to the place pose above the bin
    release  open the fingers

After each movement the operator looks at the robot (`observe`, fed by the loop's records):
if the robot's palm is not yet within tolerance of the stage's goal, the next movement is a
correction that moves the hand by the robot's remaining error (the velocity mapping makes the
robot follow the hand's motion); after `max_corrections` it moves on anyway.

The hand reaches the tracking pipeline as landmarks of the kinematic hand model
(`tracking.synthetic.SyntheticSource`) in a virtual camera: the operator's robot-frame pose is
converted to the camera frame through a fixed `WorkspaceMapping` anchored where the demo's
camera sees the hand at the robot's start pose.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.operator.open_loop import OperatorStrategy, OperatorTrajectory, sample_trajectory
from dsteleop.app.session.schema import TickRecord
from dsteleop.arbitration import HandState, so3_log
from dsteleop.tracking.mapping import MappingConfig, WorkspaceMapping
from dsteleop.tracking.synthetic import LandmarkNoise, SyntheticSource, palm_facing_camera

Array = NDArray[np.float64]

#: Where the virtual camera sees the hand when the robot is at its start pose [m, camera
#: frame]: right of and above the image centre, so the whole pick-and-place (the robot moves
#: 0.56 m to the left and 0.2 m down, 1.5x the hand) stays in view.
HAND_ANCHOR_CAM_M = (0.18, -0.06, 0.6)


@dataclass(frozen=True)
class DemoConfig:
    """Demo operator settings.

    Attributes:
        seed: seed of every random draw of the operator.
        tolerance_m: the operator is satisfied when the robot's palm is this close [m].
        tolerance_rad: ... and this close in orientation [rad].
        max_corrections: corrective movements per stage before moving on.
        closed_openness: finger openness of a closed hand.
        fps: camera frame rate [Hz].
    """

    seed: int = 0
    tolerance_m: float = 0.012
    tolerance_rad: float = 0.15
    max_corrections: int = 4
    closed_openness: float = 0.0
    fps: float = 30.0


STAGES = ("reach", "grasp", "carry", "release", "done")


class DemoOperator:
    """Closed-loop synthetic operator (module docstring). Thread-safe.

    Args:
        true_goals: returns the true (pick, place) palm poses in the base frame.
        start: the robot's start state (the hand starts there, open).
        config: demo settings.
        strategy: operator model strategy (default: the simulation study's).
    """

    def __init__(
        self,
        true_goals: Callable[[], tuple[HandState, HandState]],
        start: HandState,
        config: DemoConfig | None = None,
        strategy: OperatorStrategy | None = None,
    ) -> None:
        self.config = config or DemoConfig()
        self.strategy = strategy or OperatorStrategy()
        self._hand_strategy = dataclasses.replace(self.strategy, finger_onset=(0.0, 0.2))
        self._true_goals = true_goals
        self._rng = np.random.default_rng(self.config.seed)
        self._lock = threading.Lock()
        self._robot: HandState = start
        self._stage = 0
        self._corrections = 0
        self._hand = start
        self._seg: OperatorTrajectory | None = None
        self._seg_t0 = 0.0
        self._seen = False
        self.dt = 1.0 / self.config.fps

    @property
    def stage(self) -> str:
        return STAGES[self._stage]

    def observe(self, record: TickRecord) -> None:
        """See the robot (the loop calls this with every tick's record): its pose, and a
        task reset, after which the operator starts over from the robot's new pose."""
        if record.X_reset is not None and self._seen:  # not the loop's very first tick
            self.restart(record.X_reset)
        with self._lock:
            self._robot = record.X_current
            self._seen = True

    def restart(self, start: HandState) -> None:
        with self._lock:
            self._robot = self._hand = start
            self._stage, self._corrections, self._seg = 0, 0, None

    def hand_at(self, t_s: float) -> HandState:
        """The operator's hand (base frame, robot fingers) at source time `t_s`."""
        with self._lock:
            if self._seg is None or t_s - self._seg_t0 > float(self._seg.t_s[-1]):
                if self._seg is not None:
                    self._hand = _state_at(self._seg, -1)
                self._plan(t_s)
            assert self._seg is not None
            k = min(round((t_s - self._seg_t0) / self.dt), len(self._seg) - 1)
            return _state_at(self._seg, max(k, 0))

    def _goal_for_stage(self) -> HandState | None:
        pick, place = self._true_goals()
        closed = np.full(self._hand.n_fingers, self.config.closed_openness)
        opened = np.ones(self._hand.n_fingers)
        stage = STAGES[self._stage]
        if stage == "reach":
            return HandState(pick.position, pick.rotation, opened)
        if stage == "grasp":
            return HandState(self._hand.position, self._hand.rotation, closed)
        if stage == "carry":
            return HandState(place.position, place.rotation, closed)
        if stage == "release":
            return HandState(self._hand.position, self._hand.rotation, opened)
        return None

    def _robot_error(self, goal: HandState) -> tuple[float, float]:
        dp = float(np.linalg.norm(goal.position - self._robot.position))
        dr = float(np.linalg.norm(so3_log(goal.rotation @ self._robot.rotation.T)))
        return dp, dr

    def _plan(self, t_s: float) -> None:
        """Plan the next movement from the hand's current state."""
        goal = self._goal_for_stage()
        if goal is not None and STAGES[self._stage] in ("reach", "carry") and self._seg is not None:
            dp, dr = self._robot_error(goal)
            ok = dp <= self.config.tolerance_m and dr <= self.config.tolerance_rad
            if ok or self._corrections >= self.config.max_corrections:
                self._stage += 1
                self._corrections = 0
                goal = self._goal_for_stage()
            else:
                # Move the hand by what the robot still lacks.
                self._corrections += 1
                R_err = goal.rotation @ self._robot.rotation.T
                goal = HandState(
                    self._hand.position + (goal.position - self._robot.position),
                    R_err @ self._hand.rotation,
                    goal.openness,
                )
        elif self._seg is not None and STAGES[self._stage] in ("grasp", "release"):
            self._stage += 1
            goal = self._goal_for_stage()
        if goal is None:  # done: hold still
            goal = self._hand
        # Closing or opening the hand alone: the fingers move over most of the movement.
        hand_only = STAGES[self._stage] in ("grasp", "release")
        strategy = self._hand_strategy if hand_only else self.strategy
        self._seg = sample_trajectory(self._hand, goal, self.dt, self._rng, strategy)
        self._seg_t0 = t_s


def _state_at(traj: OperatorTrajectory, k: int) -> HandState:
    s = traj.states
    return HandState(s.position[k], s.rotation[k], s.openness[k])


def human_openness(robot_openness: Array) -> Array:
    """Robot fingers (thumb, index, middle, ring) -> human five (little follows ring)."""
    g = np.asarray(robot_openness, dtype=np.float64)
    return np.array([g[0], g[1], g[2], g[3], g[3]])


class DemoCamera:
    """Converts the operator's base-frame hand into the virtual camera's frame."""

    def __init__(self, start: HandState, mapping: MappingConfig | None = None) -> None:
        self.mapping = WorkspaceMapping(mapping or MappingConfig())
        self.mapping.anchor_at(np.array(HAND_ANCHOR_CAM_M), palm_facing_camera(), start)

    def trajectory(self, operator: DemoOperator) -> Callable[[float], tuple[HandState, Array]]:
        def at(t_s: float) -> tuple[HandState, Array]:
            X = operator.hand_at(t_s)
            p_cam, R_cam = self.mapping.to_camera(X)
            g5 = human_openness(X.openness)
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
