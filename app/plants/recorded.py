"""The robot side of a recorded session, played back as a `ports.Plant`.

Each tick returns what the robot and the task reported when the session was recorded (the
achieved state, phase, task events, outcome), whatever the loop commands. A replay against
the recorded robot is therefore open loop: no physics runs, so the loop and the
arbitration see exactly the states they saw live, on any machine. In the recorded mode it
reproduces the recorded arbitration (what the sample sessions' check relies on); in another
mode it shows what that mode would have computed along the same robot path. Where another
mode would have taken the robot is the simulated replay's question (`KitchenPlant`).
"""

from __future__ import annotations

from typing import Any

from dsteleop.app.ports import PlantStep
from dsteleop.app.session.reader import Session
from dsteleop.arbitration import HandState
from dsteleop.errors import InputError
from dsteleop.robot.scene import SceneGeometry
from dsteleop.robot.task import Phase


class RecordedPlant:
    """Plays back `session`'s robot (module docstring).

    Raises:
        InputError: the session has no ticks, or was recorded before the robot's reset
            states were (it can only be replayed against the simulated robot).
    """

    def __init__(self, session: Session) -> None:
        self._records = session.records
        self.finger_names = session.dims[6:]
        self._meta = dict(session.meta.get("plant", {}))
        self._k = 0
        if not self._records or self._records[0].X_reset is None:
            raise InputError(
                f"{session.folder}: recorded without the robot's reset states (X_reset); "
                "replay it against the simulated robot"
            )

    def _record(self) -> Any:
        if self._k >= len(self._records):
            raise InputError("the replay ran past the last recorded tick")
        return self._records[self._k]

    def reset(self, utensil: str | None = None) -> HandState:
        X = self._record().X_reset
        if X is None:
            raise InputError(f"tick {self._k}: a reset the recording does not hold")
        return X

    def goal(self) -> HandState | None:
        r = self._record()
        prev = self._records[self._k - 1] if self._k > 0 else None
        if prev is not None and prev.phase is Phase.DONE and r.X_reset is None:
            return None  # schema 1 recorded the achieved state as the goal once done
        return r.X_goal

    def apply(self, X_next: HandState) -> PlantStep:
        r = self._record()
        self._k += 1
        return r.plant

    def set_goal_noise(self, sigma_m: float) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return self._meta

    def scene(self) -> SceneGeometry | None:
        return None

    def close(self) -> None:
        pass
