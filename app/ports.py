"""The seams of the loop: what it needs from a hand, a robot, a clock and its observers.

Each port is a small protocol owned by no implementation, so an implementation imports this
module and never the loop, and the loop cannot tell implementations apart:

    HandInput   the operator: a camera, a video, the demo operator (through the tracking
                pipeline and the workspace mapping), or a recorded session
    Plant       the robot and its task: the PyBullet kitchen, a recorded robot, a test fake
    Clock       time: the monotonic clock live, a manual clock headless and in tests
    InputArrivals  when new hand input is ready, for a loop whose tick follows the camera
                (a hand with frames of its own: a camera or a video played live)
    Observer    anyone who sees the ticks: the browser view, the demo operator's eyes, a
                recorder, a test; called once per tick from the loop's thread, and must not
                block (a one-slot mailbox, `loop.broadcast`, decouples slow observers)

The data that crosses them is typed here too: `HumanInput` (a mapped hand sample) and
`PlantStep` (what the robot and the task report after a tick, with the task's own typed
phase, events and outcome from `robot.task`, and the scene poses of `robot.scene`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from dsteleop.arbitration import HandState
from dsteleop.robot.scene import SceneGeometry, ScenePoses
from dsteleop.robot.task import EventKind, Outcome, Phase, TaskEvent
from dsteleop.tracking.types import HandSample

if TYPE_CHECKING:
    from dsteleop.app.session.schema import TickRecord


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
    """What the robot and the task report after one tick.

    Attributes:
        X_current: the robot's achieved palm state (base frame).
        phase: the task's phase after the tick.
        events: task events of this tick.
        outcome: the outcome, on the tick it is decided and after; None before.
        scene: world poses of the scene's frames for a viewer, or None.
    """

    X_current: HandState
    phase: Phase
    events: tuple[TaskEvent, ...] = ()
    outcome: Outcome | None = None
    scene: ScenePoses | None = None

    @property
    def segment_changed(self) -> bool:
        """A new goal became active this tick (the place segment started)."""
        return any(e.kind is EventKind.GOAL for e in self.events)


class Plant(Protocol):
    """The robot and its task as the loop sees them."""

    @property
    def finger_names(self) -> tuple[str, ...]: ...

    def reset(self, utensil: str | None = None) -> HandState:
        """Start the task again; returns the robot's state at the start."""
        ...

    def goal(self) -> HandState | None:
        """The active goal as the robot knows it (noisy), or None once the task is done."""
        ...

    def apply(self, X_next: HandState) -> PlantStep:
        """Command the state, advance one tick, report."""
        ...

    def set_goal_noise(self, sigma_m: float) -> None:
        """New goal noise, from the next reset."""
        ...

    def describe(self) -> dict[str, Any]:
        """Everything that rebuilds the same plant (recorded with a session)."""
        ...

    def scene(self) -> SceneGeometry | None:
        """The static scene description a viewer draws, or None."""
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
