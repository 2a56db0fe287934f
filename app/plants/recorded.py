"""The robot and the task of a recorded session, played back as a `ports.Robot` and a
`ports.Task` (`recorded_pair`).

Each tick returns what the robot and the task reported when the session was recorded (the
achieved state and joint positions, phase, task events, outcome), whatever the loop
commands; a session recorded without joints (schema 3 and older, or a robot that reports
none) plays back a robot without joints. A replay against
the recorded robot is therefore open loop: no physics runs, so the loop and the
arbitration see exactly the states they saw live, on any machine. In the recorded mode it
reproduces the recorded arbitration (what the sample sessions' check relies on); in another
mode it shows what that mode would have computed along the same robot path. Where another
mode would have taken the robot is the simulated replay's question (`plants.kitchen`).

The two share one cursor over the records: the task's `update` moves it to the next tick.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.plants.described import limits_of
from dsteleop.app.ports import RobotLimits, RobotState, TaskStep
from dsteleop.app.session.reader import Session
from dsteleop.app.session.schema import TickRecord
from dsteleop.arbitration import HandState
from dsteleop.errors import InputError
from dsteleop.robot.description import description_from_record
from dsteleop.robot.scene import SceneGeometry
from dsteleop.robot.task import Candidates, Phase


class _Cursor:
    """The tick the playback is at."""

    def __init__(self, session: Session) -> None:
        self.records = session.records
        self.folder = session.folder
        self.k = 0
        if not self.records or self.records[0].X_reset is None:
            raise InputError(
                f"{session.folder}: recorded without the robot's reset states (X_reset); "
                "replay it against the simulated robot"
            )

    def record(self) -> TickRecord:
        if self.k >= len(self.records):
            raise InputError("the replay ran past the last recorded tick")
        return self.records[self.k]


class RecordedRobot:
    """Plays back a session's robot (module docstring)."""

    def __init__(self, cursor: _Cursor, session: Session) -> None:
        self._c = cursor
        self.finger_names = session.dims[6:]
        self._meta = dict(session.meta.get("robot") or {"kind": "recorded"})
        self.name = str(self._meta.get("name", "recorded"))
        self.joint_names = session.joint_names
        self.joint_units = session.joint_units
        self.limits: RobotLimits = limits_of(description_from_record(self._meta))

    def _joints(self, q: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """A record's joints in `joint_names` order (NaN where the record holds none).

        Raises:
            InputError: the record holds another number of joints than the session names.
        """
        n = len(self.joint_names)
        if q is None:
            return np.full(n, np.nan)
        if q.shape != (n,):
            raise InputError(
                f"{self._c.folder}: tick {self._c.k} holds {q.size} joint positions for the "
                f"{n} joints of the session's joint_names"
            )
        return q

    def reset(self, now_s: float) -> RobotState:
        r = self._c.record()
        if r.X_reset is None:
            raise InputError(f"tick {self._c.k}: a reset the recording does not hold")
        return RobotState(r.X_reset, self._joints(r.joints_reset), now_s)

    def apply(self, X_cmd: HandState, seq: int, now_s: float) -> None:
        pass

    def state(self, now_s: float) -> RobotState | None:
        p = self._c.record().plant
        return RobotState(p.X_current, self._joints(p.joints), now_s)

    def describe(self) -> dict[str, Any]:
        return self._meta

    def scene(self) -> SceneGeometry | None:
        return None

    def close(self) -> None:
        pass


class RecordedTask:
    """Plays back a session's task (module docstring)."""

    def __init__(self, cursor: _Cursor, session: Session) -> None:
        self._c = cursor
        self._meta = dict(session.meta.get("plant", {}))

    def reset(self, utensil: str | None = None) -> None:
        pass

    def goal(self) -> HandState | None:
        c = self._c
        r = c.record()
        prev = c.records[c.k - 1] if c.k > 0 else None
        if prev is not None and prev.phase is Phase.DONE and r.X_reset is None:
            return None  # schema 1 recorded the achieved state as the goal once done
        return r.X_goal

    def candidates(self) -> Candidates | None:
        """None: a recorded task plays back the goal the robot sought (`goal`), inferred or
        told."""
        return None

    def true_goals(self, utensil: str | None = None) -> tuple[HandState, HandState]:
        raise InputError("a recorded task has no true goals to show a demo operator")

    def update(self, state: RobotState) -> TaskStep:
        r = self._c.record()
        self._c.k += 1
        p = r.plant
        return TaskStep(p.phase, p.events, p.outcome, p.scene)

    def set_goal_noise(self, sigma_m: float) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return self._meta

    def scene(self) -> SceneGeometry | None:
        return None

    def close(self) -> None:
        pass


def recorded_pair(session: Session) -> tuple[RecordedRobot, RecordedTask]:
    """The session's robot and task, played back on one cursor.

    Raises:
        InputError: the session has no ticks, or was recorded before the robot's reset
            states were (it can only be replayed against the simulated robot).
    """
    cursor = _Cursor(session)
    return RecordedRobot(cursor, session), RecordedTask(cursor, session)
