"""Fakes of the loop's ports, for testing the loop's own logic without PyBullet or a camera.

`FakeRobot` is a kinematic robot (it reaches each commanded state exactly, or with a
first-order lag); `FakeTask` a two-segment task judging its measured state: the pick segment
ends when the palm has been within `tolerance_m` of the pick goal for `hold_ticks` ticks, then
the place goal is active and the task succeeds when the palm reaches it. `fake_world` builds
the pair. `ScriptedHand` is the operator's hand from a path in the robot base frame, sampled
like a 30 Hz camera, with the same re-anchoring semantics as the workspace mapping (a
returning hand maps to where the loop asks). None of them imports PyBullet.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.ports import (
    NO_HAND,
    HumanInput,
    InputArrivals,
    RobotLimits,
    RobotState,
    TaskStep,
)
from dsteleop.arbitration import HandState, so3_exp
from dsteleop.robot.scene import SceneGeometry
from dsteleop.robot.task import Candidates, EventKind, Outcome, Phase, TaskEvent

Array = NDArray[np.float64]
FINGERS = ("thumb", "index", "middle", "ring")
DT = 1.0 / 30.0


def state(
    p: tuple[float, float, float],
    rv: tuple[float, float, float] = (0.0, 0.0, 0.0),
    g: float = 1.0,
    n_fingers: int = 4,
) -> HandState:
    return HandState(
        np.array(p, dtype=np.float64),
        so3_exp(np.array(rv, dtype=np.float64)),
        np.full(n_fingers, g),
    )


class FakeRobot:
    """A kinematic robot (module docstring).

    Args:
        start: the robot's state at every reset.
        lag: 0 reaches each command exactly; otherwise X moves this fraction of the way.
        fingers: its openness dimensions (default the four-finger hand's).
        silent_after: stop reporting new states after this many commands (a lost robot).

    Attributes:
        lost_between: (from, to) on the loop's clock [s]: no new states in between (a link
            whose far end stopped publishing, then came back), or None.
    """

    def __init__(
        self,
        start: HandState | None = None,
        lag: float = 0.0,
        fingers: tuple[str, ...] = FINGERS,
        silent_after: int | None = None,
    ) -> None:
        self.finger_names = fingers
        self.start = start or state((0.5, 0.3, 0.4), n_fingers=len(fingers))
        self.lag = lag
        self.silent_after = silent_after
        self.name = "fake"
        self.joint_names: tuple[str, ...] = ()
        self.joint_units: tuple[str, ...] = ()
        self.limits = RobotLimits((0.0, -1.0, 0.0), (1.0, 1.0, 1.0), 0.25, 1.0, 4.0)
        self.resets = 0
        self.commands: list[HandState] = []
        self.seqs: list[int] = []
        self.X = self.start
        self._stamp_s = 0.0
        self.lost_between: tuple[float, float] | None = None

    def reset(self, now_s: float) -> RobotState:
        self.X = self.start
        self.resets += 1
        self._stamp_s = now_s
        return RobotState(self.X, np.zeros(0), now_s)

    def apply(self, X_cmd: HandState, seq: int, now_s: float) -> None:
        self.commands.append(X_cmd)
        self.seqs.append(seq)
        if self.silent_after is not None and len(self.commands) > self.silent_after:
            return
        if self.lost_between is not None and self.lost_between[0] <= now_s < self.lost_between[1]:
            return
        if self.lag:
            a = 1.0 - self.lag
            self.X = HandState(
                self.X.position + a * (X_cmd.position - self.X.position),
                X_cmd.rotation,
                X_cmd.openness,
            )
        else:
            self.X = X_cmd
        self._stamp_s = now_s

    def state(self, now_s: float) -> RobotState | None:
        return RobotState(self.X, np.zeros(0), self._stamp_s)

    def describe(self) -> dict[str, Any]:
        return {"kind": "fake", "name": self.name}

    def scene(self) -> SceneGeometry | None:
        return None

    def close(self) -> None:
        pass


class FakeTask:
    """A pick-then-place task on a kinematic robot (module docstring).

    Args:
        pick, place: the goals the robot knows.
        tolerance_m: how close counts as at a goal [m].
        hold_ticks: ticks at the pick goal before the place segment starts.
        n_fingers: the robot's openness dimensions.
    """

    def __init__(
        self,
        pick: HandState | None = None,
        place: HandState | None = None,
        tolerance_m: float = 0.01,
        hold_ticks: int = 3,
        n_fingers: int = 4,
    ) -> None:
        self.pick = pick or state((0.5, 0.1, 0.2), g=0.0, n_fingers=n_fingers)
        self.place = place or state((0.5, -0.2, 0.4), g=1.0, n_fingers=n_fingers)
        self.tolerance_m = tolerance_m
        self.hold_ticks = hold_ticks
        self.resets = 0
        self.updates = 0
        self.reset()

    def reset(self, utensil: str | None = None) -> None:
        self.phase = Phase.PICK
        self.outcome: Outcome | None = None
        self._held = 0
        self.t_s = 0.0
        self.resets += 1

    def goal(self) -> HandState | None:
        if self.phase is Phase.DONE:
            return None
        return self.pick if self.phase is Phase.PICK else self.place

    def candidates(self) -> Candidates | None:
        return None

    def true_goals(self, utensil: str | None = None) -> tuple[HandState, HandState]:
        return self.pick, self.place

    def update(self, robot: RobotState) -> TaskStep:
        self.updates += 1
        self.t_s += DT
        events: list[TaskEvent] = []
        goal = self.goal()
        X = robot.X
        if goal is not None:
            near = float(np.linalg.norm(X.position - goal.position)) < self.tolerance_m
            if self.phase is Phase.PICK:
                self._held = self._held + 1 if near else 0
                if self._held >= self.hold_ticks:
                    self.phase = Phase.PLACE
                    events += [
                        TaskEvent(EventKind.GRASP, self.t_s, "thing"),
                        TaskEvent(EventKind.GOAL, self.t_s, "place"),
                    ]
            elif near:
                self.phase = Phase.DONE
                self.outcome = Outcome(True, "in_bin", self.t_s, "thing")
                events.append(TaskEvent(EventKind.SUCCESS, self.t_s, "in_bin"))
        return TaskStep(self.phase, tuple(events), self.outcome)

    def set_goal_noise(self, sigma_m: float) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return {"kind": "fake", "utensil": "thing"}

    def scene(self) -> SceneGeometry | None:
        return None

    def close(self) -> None:
        pass


def fake_world(
    start: HandState | None = None,
    pick: HandState | None = None,
    place: HandState | None = None,
    lag: float = 0.0,
    fingers: tuple[str, ...] = FINGERS,
    **task: Any,
) -> tuple[FakeRobot, FakeTask]:
    """A `FakeRobot` and a `FakeTask` (their arguments)."""
    robot = FakeRobot(start, lag, fingers)
    return robot, FakeTask(pick, place, n_fingers=len(fingers), **task)


Path = Callable[[float], HandState | None]


class ScriptedHand:
    """The operator's hand from `path(t)` (robot base frame; None: not seen), sampled at
    `fps` and captured at k / fps, like a camera (module docstring).

    Args:
        path: the hand's pose over time.
        fps: samples per second.
        input_delay_s: samples reach the loop this much later than captured.
        corrupt: rewrites a mapped sample before the loop sees it (NaN, a stalled camera).
    """

    def __init__(
        self,
        path: Path,
        fps: float = 30.0,
        input_delay_s: float = 0.0,
        corrupt: Callable[[HumanInput], HumanInput] | None = None,
    ) -> None:
        self.path = path
        self.fps = fps
        self.input_delay_s = input_delay_s
        self.corrupt = corrupt
        self._offset_p = np.zeros(3)
        self._offset_R = np.eye(3)
        self._raw: dict[int, HandState] = {}
        self.calibrations = 0
        self.closed = False

    def _map(self, raw: HandState) -> HandState:
        return HandState(
            self._offset_R @ raw.position + self._offset_p,
            self._offset_R @ raw.rotation,
            raw.openness,
        )

    def poll(self, now_s: float) -> HumanInput | None:
        k = math.floor((now_s - self.input_delay_s) * self.fps + 1e-9)
        if k < 0:
            return None
        t = k / self.fps
        raw = self.path(t)
        if raw is None:
            inp = HumanInput(k, t, t, None, NO_HAND)
        else:
            self._raw[k] = raw
            inp = HumanInput(k, t, t, self._map(raw))
        return self.corrupt(inp) if self.corrupt is not None else inp

    @property
    def arrivals(self) -> InputArrivals | None:
        """None: the loop paces a scripted hand on its own clock."""
        return None

    def reanchor(self, inp: HumanInput, X_target: HandState) -> HumanInput:
        raw = self._raw.get(inp.seq)
        if raw is None or inp.X_human is None:
            return inp
        self._offset_R = X_target.rotation @ raw.rotation.T
        self._offset_p = X_target.position - self._offset_R @ raw.position
        return HumanInput(inp.seq, inp.t_capture_s, inp.t_tracked_s, self._map(raw))

    def calibrate(self) -> None:
        self.calibrations += 1

    @property
    def finished(self) -> bool:
        return False

    def describe(self) -> str:
        return "scripted hand"

    def mapping_config(self) -> dict[str, Any]:
        return {}

    end_reason = "script ended"

    def start(self) -> None:
        pass

    def close(self) -> None:
        self.closed = True


class FramedHand(ScriptedHand):
    """A `ScriptedHand` seen through a camera with a tracker, on a `ManualClock`: frame k is
    captured at k / fps (until `stall_at_s`: then the camera stalls) and ready once tracked,
    `tracking_s(k)` after its capture, in order (a frame is never ready before the previous);
    `poll` returns the newest ready frame. Its `arrivals` (`ports.InputArrivals`) wait on the
    manual clock (advancing it), so a loop's tick can follow the frames deterministically.

    Args:
        path: the hand's pose over time (robot base frame).
        clock: the loop's manual clock.
        fps: capture rate [Hz].
        tracking_s: tracking time of frame k [s].
        stall_at_s: no frame is captured from this time on [s].
        duration_s: frames are made up to this capture time [s].
    """

    def __init__(
        self,
        path: Path,
        clock: Any,
        fps: float = 30.0,
        tracking_s: Callable[[int], float] = lambda k: 0.02,
        stall_at_s: float = math.inf,
        duration_s: float = 30.0,
    ) -> None:
        super().__init__(path, fps)
        self.clock = clock
        self.capture_s: list[float] = []
        self.ready_s: list[float] = []
        k = 0
        while k / fps < min(stall_at_s, duration_s):
            prev = self.ready_s[-1] if self.ready_s else -math.inf
            self.capture_s.append(k / fps)
            self.ready_s.append(max(prev, k / fps + tracking_s(k)))
            k += 1
        self.polled = -1

    @property
    def arrivals(self) -> FramedHand:
        return self

    def _newest(self, now_s: float) -> int:
        return bisect.bisect_right(self.ready_s, now_s + 1e-12) - 1

    def poll(self, now_s: float) -> HumanInput | None:
        k = self._newest(now_s)
        if k < 0:
            return None
        self.polled = max(self.polled, k)
        t, ready = self.capture_s[k], self.ready_s[k]
        raw = self.path(t)
        if raw is None:
            return HumanInput(k, t, ready, None, NO_HAND)
        self._raw[k] = raw
        return HumanInput(k, t, ready, self._map(raw))

    def wait_newer(self, until_s: float) -> float | None:
        k = self._newest(self.clock.now())
        if k > self.polled:
            return self.ready_s[k]
        j = self.polled + 1  # the next frame to become ready
        if j < len(self.ready_s) and self.ready_s[j] <= until_s:
            self.clock.sleep_until(self.ready_s[j])
            return self.ready_s[j]
        self.clock.sleep_until(until_s)
        return None
