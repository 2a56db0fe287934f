"""The seams of the loop: what it needs from a hand, a robot, a clock and its observers.

Each port is a small protocol owned by no implementation, so an implementation imports this
module and never the loop, and the loop cannot tell implementations apart:

    HandInput   the operator: a camera, a video, the demo operator (through the tracking
                pipeline and the workspace mapping), or a recorded session
    Robot       the arm and its hand: reset, apply a command, read the measured state, its
                limits and scene; a simulated PyBullet robot of any description, a linked
                robot, a recorded robot, a test fake
    Task        what the robot is asked to do and how it went: the goals (true, and as the
                robot knows them, with noise), phases, events, outcome, reset; the kitchen
                pick-and-place (judging any robot that can reach it), a recorded task, a fake
    Clock       time: the monotonic clock live, a manual clock headless and in tests
    InputArrivals  when new hand input is ready, for a loop whose tick follows the camera
                (a hand with frames of its own: a camera or a video played live)
    Observer    anyone who sees the ticks: the browser view, the demo operator's eyes, a
                recorder, a test; called once per tick from the loop's thread, and must not
                block (a one-slot mailbox, `loop.broadcast`, decouples slow observers)
    Output      where a run writes what happened, beside the session the loop records: the
                camera's video, a LeRobot dataset, a Rerun recording (app/outputs/, each a
                plug-in in a registry); an observer that is also told when a session starts
                and stops and when each recorded episode ends

The data that crosses them is typed here too: `HumanInput` (a mapped hand sample),
`RobotState` and `RobotLimits` (the robot's measured state and its limits), `TaskStep` (the
task's typed phase, events and outcome from `robot.task` after a tick, and the scene poses
of `robot.scene`), and `PlantStep`, the two reports of a tick together as a record holds them.

The Robot port's names are a contract shared with the linked robot (issue 25): fields may be
added, none renamed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import HandState
from dsteleop.arbitration.se3 import so3_exp, so3_log
from dsteleop.errors import ConfigError
from dsteleop.robot.scene import SceneGeometry, ScenePoses
from dsteleop.robot.task import Candidates, EventKind, Outcome, Phase, TaskEvent
from dsteleop.tracking.types import HandSample

if TYPE_CHECKING:
    from pathlib import Path

    from dsteleop.app.session.episodes import Episode
    from dsteleop.app.session.schema import TickRecord
    from dsteleop.tracking.sources import FrameSource


NO_HAND = "no hand"
INVALID = "invalid hand data"


@dataclass(frozen=True)
class HumanInput:
    """One tracked-and-mapped hand sample.

    Attributes:
        seq: frame number of the source.
        t_capture_s: capture time [s] on the loop's clock.
        t_tracked_s: when tracking of the frame finished [s].
        X_human: the hand in the robot base frame with the robot's fingers, or None when
            there is no usable hand in this sample.
        reason: "" when `X_human` is usable, else why not (`NO_HAND`, `INVALID`).
        sample: the tracker's sample (landmarks, camera-frame pose, the frame's pixels when
            it had any) for recording and the view; None for input read back without it.
    """

    seq: int
    t_capture_s: float
    t_tracked_s: float
    X_human: HandState | None
    reason: str = ""
    sample: HandSample | None = None


class HandInput(Protocol):
    """What the loop needs of the operator's hand."""

    def start(self) -> None:
        """Begin delivering input (a file starts playing); the loop calls it as it starts
        running. Idempotent."""
        ...

    def poll(self, now_s: float) -> HumanInput | None:
        """The newest input at loop time `now_s` (never blocks), or None before the first."""
        ...

    @property
    def arrivals(self) -> InputArrivals | None:
        """When new input becomes ready, for a tick that follows the camera's frames; None
        for a source the loop paces on its own clock (the demo, a recording, a headless
        reader)."""
        ...

    def reanchor(self, inp: HumanInput, X_target: HandState) -> HumanInput:
        """Make the hand of `inp` map to `X_target` from now on; return it re-mapped."""
        ...

    def calibrate(self) -> None:
        """Re-centre the mapping on the current hand without a jump."""
        ...

    @property
    def finished(self) -> bool:
        """The source has no more input (a file that ended); False for live sources."""
        ...

    @property
    def end_reason(self) -> str:
        """What the loop says once `finished` input goes stale ("video ended", ...)."""
        ...

    def describe(self) -> str: ...

    def mapping_config(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class PlantStep:
    """What the robot and the task reported after one tick, together (a tick's record).

    Attributes:
        X_current: the robot's achieved palm state (base frame).
        phase: the task's phase after the tick.
        events: task events of this tick.
        outcome: the outcome, on the tick it is decided and after; None before.
        scene: world poses of the scene's frames for a viewer, or None.
        joints: the robot's measured joint positions after the tick [rad, or m for a
            prismatic joint], in `Robot.joint_names` order; None when the robot reports
            none (no joints, or a record that holds none).
    """

    X_current: HandState
    phase: Phase
    events: tuple[TaskEvent, ...] = ()
    outcome: Outcome | None = None
    scene: ScenePoses | None = None
    joints: NDArray[np.float64] | None = None

    @classmethod
    def of(
        cls, X_current: HandState, step: TaskStep, joints: NDArray[np.float64] | None = None
    ) -> PlantStep:
        """The robot's achieved state (and joints) and the task's report of one tick."""
        return cls(X_current, step.phase, step.events, step.outcome, step.scene, joints)

    @property
    def segment_changed(self) -> bool:
        """A new goal became active this tick (the place segment started)."""
        return any(e.kind is EventKind.GOAL for e in self.events)


#: A robot state older than this on the loop's clock means the robot is lost (halt) [s].
ROBOT_STALE_S = 0.2
ROBOT_LOST = "robot lost"


@dataclass(frozen=True)
class RobotLimits:
    """What the robot allows: the palm's workspace box and speed limits (base frame).

    Attributes:
        workspace_min_m: lower corner of the palm position box [m].
        workspace_max_m: upper corner [m].
        max_speed_m_s: palm linear speed limit [m/s].
        max_rate_rad_s: palm angular speed limit [rad/s].
        max_finger_rate_per_s: openness change limit [1/s].
    """

    workspace_min_m: tuple[float, float, float]
    workspace_max_m: tuple[float, float, float]
    max_speed_m_s: float
    max_rate_rad_s: float
    max_finger_rate_per_s: float

    def clamp(self, X_prev: HandState, X_cmd: HandState, dt_s: float) -> HandState:
        """X_cmd inside the workspace box and within the speed limits from X_prev over dt_s:
        the position step scaled to at most max_speed dt, then clipped into the box; the
        rotation step (the rotation vector of R_cmd R_prev^T) scaled to at most max_rate
        dt; each finger's change clipped to max_finger_rate dt, then into [0, 1]."""
        dt = max(float(dt_s), 0.0)
        dp = X_cmd.position - X_prev.position
        n = float(np.linalg.norm(dp))
        step = self.max_speed_m_s * dt
        if n > step:
            dp = dp * (step / n)
        p = np.clip(X_prev.position + dp, self.workspace_min_m, self.workspace_max_m)
        w = so3_log(X_cmd.rotation @ X_prev.rotation.T)
        a = float(np.linalg.norm(w))
        turn = self.max_rate_rad_s * dt
        R = X_cmd.rotation if a <= turn else so3_exp(w * (turn / a)) @ X_prev.rotation
        dg = np.clip(
            X_cmd.openness - X_prev.openness,
            -self.max_finger_rate_per_s * dt,
            self.max_finger_rate_per_s * dt,
        )
        g = np.clip(X_prev.openness + dg, 0.0, 1.0)
        return HandState(p, R, g)

    def __post_init__(self) -> None:
        lo, hi = self.workspace_min_m, self.workspace_max_m
        if len(lo) != 3 or len(hi) != 3 or not all(math.isfinite(v) for v in (*lo, *hi)):
            raise ConfigError("robot limits: the workspace corners must be 3 finite numbers")
        if any(a >= b for a, b in zip(lo, hi, strict=True)):
            raise ConfigError(f"robot limits: workspace_min_m {lo} must be below max {hi}")
        for name in ("max_speed_m_s", "max_rate_rad_s", "max_finger_rate_per_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"robot limits: {name} must be finite and > 0, got {v!r}")


@dataclass(frozen=True)
class RobotState:
    """The robot as measured.

    Attributes:
        X: achieved palm pose (base frame) and finger openness in [0, 1] (the commanded
            set-point of a simulated hand, `robot.arm`).
        joints: joint positions [rad, or m for a prismatic joint], in the order of
            `Robot.joint_names`.
        stamp_s: when it was measured, on the loop's clock [s].
    """

    X: HandState
    joints: NDArray[np.float64]
    stamp_s: float


class Robot(Protocol):
    """The arm and its hand as the loop sees them (the contract of docs/ARCHITECTURE.md)."""

    @property
    def name(self) -> str: ...

    @property
    def finger_names(self) -> tuple[str, ...]:
        """The openness dimensions: ("thumb", "index", "middle", "ring"), ("gripper",)."""
        ...

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The joints of `RobotState.joints`, in order (the arm's, then the fingers'); ()
        for a robot that reports none."""
        ...

    @property
    def joint_units(self) -> tuple[str, ...]:
        """The unit of each joint's position, in `joint_names` order: "rad" (revolute) or
        "m" (prismatic)."""
        ...

    @property
    def limits(self) -> RobotLimits: ...

    def reset(self, now_s: float) -> RobotState:
        """To the home pose; returns the state there."""
        ...

    def apply(self, X_cmd: HandState, seq: int, now_s: float) -> None:
        """This tick's command (`seq` increases by one per tick). A simulated robot also
        advances its physics by one loop period; a linked robot publishes it and returns."""
        ...

    def state(self, now_s: float) -> RobotState | None:
        """The newest measured state; None = none yet. The loop treats a state whose
        `stamp_s` is older than `ROBOT_STALE_S` as a lost robot (halt)."""
        ...

    def describe(self) -> dict[str, Any]:
        """What rebuilds it (recorded with a session)."""
        ...

    def scene(self) -> SceneGeometry | None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class TaskStep:
    """What the task reports after one tick.

    Attributes:
        phase: the task's phase after the tick.
        events: task events of this tick.
        outcome: the outcome, on the tick it is decided and after; None before.
        scene: world poses of the scene's frames for a viewer, or None.
    """

    phase: Phase
    events: tuple[TaskEvent, ...] = ()
    outcome: Outcome | None = None
    scene: ScenePoses | None = None


class Task(Protocol):
    """What the robot is asked to do, and how it went."""

    def reset(self, utensil: str | None = None) -> None:
        """Set the task up again (a new trial); the loop then resets the robot."""
        ...

    def goal(self) -> HandState | None:
        """The active goal as the robot knows it (noisy), or None once the task is done, or
        while the robot is not told its goal (`candidates` says what it chooses among)."""
        ...

    def candidates(self) -> Candidates | None:
        """The goals a robot that is not told its goal chooses among (`--goal infer`): their
        poses as it knows them and its uncertainty of each; None when it is told its goal,
        or once the task is done."""
        ...

    def true_goals(self, utensil: str | None = None) -> tuple[HandState, HandState]:
        """The true (pick, place) palm poses, open hand, as a person watching sees them: the
        pick of `utensil` (None: the task's; a person may want another one than the robot
        was told, or change its mind)."""
        ...

    def update(self, state: RobotState) -> TaskStep:
        """Judge the robot's measured state after a tick: phase, events, outcome."""
        ...

    def set_goal_noise(self, sigma_m: float) -> None:
        """New goal noise, from the next reset."""
        ...

    def describe(self) -> dict[str, Any]:
        """Everything that rebuilds the same task (recorded with a session)."""
        ...

    def scene(self) -> SceneGeometry | None:
        """The static scene description a viewer draws (the task's world), or None."""
        ...

    def close(self) -> None: ...


class Clock(Protocol):
    """A monotonic clock in seconds that can sleep until a time."""

    def now(self) -> float: ...

    def sleep_until(self, t_s: float) -> None: ...


class InputArrivals(Protocol):
    """When new hand input is ready (`loop.timing.RateClock`'s frame-following schedule).

    "New" is an input the hand has not returned from `poll` yet; it is ready when it may
    drive the loop: tracked, and (with an injected delay) at least the delay old.
    """

    def wait_newer(self, until_s: float) -> float | None:
        """Block until an input the hand has not returned from `poll` yet is ready, or until
        loop time `until_s`; returns at once when one is ready already or `until_s` is past.

        Returns:
            The loop time the newest such input became ready [s], or None when none is.
        """
        ...


class Observer(Protocol):
    """Sees every tick; called from the loop's thread, must return at once."""

    def observe(self, record: TickRecord) -> None: ...


class Output(Observer, Protocol):
    """Where a run writes what happened (module docstring; `outputs.OutputBase` does nothing
    in every hook, so an output writes only the hooks it needs). The loop calls `observe`
    each tick after its own recording (from its thread: must not block), `start_session` and
    `stop_session` around each session it records, and `episode` as each recorded episode's
    ticks are written (from the recorder's thread). The composition calls `wrap_source`
    before the hand is built, `close` after the loop is closed, and `summary` for the
    command's summary line."""

    def wrap_source(self, source: FrameSource) -> FrameSource:
        """The hand's frames pass through the returned source (the video records them)."""
        ...

    def start_session(self, folder: Path) -> None:
        """A session starts recording into `folder` (a new session folder)."""
        ...

    def stop_session(self) -> None:
        """The session is closing: finish what is written beside it (its last episode may
        still follow, on the recorder's thread)."""
        ...

    def episode(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        """An episode ended and its ticks are in the session (`session.writer.EpisodeSink`)."""
        ...

    def summary(self) -> dict[str, Any] | None:
        """What it wrote, for the command's summary (None: nothing to say)."""
        ...

    def close(self) -> None:
        """Write what is left and release it (after the loop is closed)."""
        ...
