"""The kitchen over the link: today's `ports.Plant` with the arm and its world at the far end.

`dsteleop run --robot zenoh:CONFIG` builds this instead of the in-process `KitchenPlant`:
the arm, the utensils and the task's bookkeeping run in `dsteleop robot-sim` (the world is
where the arm is); this plant sends each tick's command through `ZenohRobot` and reads back
the measured palm state and the task's status (phase, known goal, true goals, events,
outcome: the `task` topic, a std_msgs/String of JSON that only the simulated far end
publishes). It runs in real time (the far end's physics keeps its own clock): `apply`
publishes and returns the newest state the far end reported, one link latency and up to one
far-end period old.

An adapter until the loop takes the `Robot` and `Task` ports (issue 25): a stale robot state
is reported in `PlantStep.robot_lost`, which the loop treats as a lost hand (halt).
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

from dsteleop.app.link import ros
from dsteleop.app.link.config import LinkConfig
from dsteleop.app.link.far import state_from_json
from dsteleop.app.link.near import ZenohRobot
from dsteleop.app.link.session import Received, Subscription
from dsteleop.app.ports import PlantStep
from dsteleop.arbitration import HandState
from dsteleop.errors import ConfigError, InputError
from dsteleop.robot.scene import SceneGeometry
from dsteleop.robot.task import EventKind, Outcome, Phase, TaskEvent


class LinkedKitchenPlant:
    """The kitchen task with the arm at the far end of the link (module docstring).

    Args:
        config: the link's configuration.
        utensil: the utensil the far end was started with (recorded only).
        seed: the seed the far end was started with (recorded only).
    """

    def __init__(self, config: LinkConfig, utensil: str = "spoon", seed: int = 0) -> None:
        self.config = config
        self.utensil = utensil
        self.seed = seed
        self.robot = ZenohRobot(config)
        self._lock = threading.Lock()
        self._events: list[TaskEvent] = []
        self._status: dict[str, Any] | None = None
        self._task_in: Subscription[str] = Subscription(
            self.robot.session,
            config.domain_id,
            config.topics.task,
            ros.STRING,
            ros.decode_string,
            self._on_status,
        )
        self._t0 = time.monotonic()
        self._seq = 0

    @property
    def finger_names(self) -> tuple[str, ...]:
        return self.config.finger_names

    def _on_status(self, rec: Received[str]) -> None:
        try:
            status = json.loads(rec.msg)
            events = [TaskEvent(EventKind(k), float(t), str(d)) for k, t, d in status["events"]]
        except (ValueError, KeyError, TypeError):
            return  # a malformed status is ignored; the robot state still arrives
        with self._lock:
            self._status = status
            self._events.extend(events)

    def _now(self) -> float:
        return time.monotonic() - self._t0

    def reset(self, utensil: str | None = None) -> HandState:
        """Wait for the far end's state and task status; the robot stays where it is."""
        if utensil is not None and utensil != self.utensil:
            raise ConfigError(
                f"robot link: the far end runs the {self.utensil}; restart robot-sim with "
                f"--utensil {utensil}"
            )
        X = self.robot.reset(self._now()).X
        t_end = time.monotonic() + self.config.connect_timeout_s
        while self._status_now() is None:
            self._task_in.newest()  # raises on a wrong message
            if time.monotonic() > t_end:
                raise InputError(
                    f"robot link: no task status on {self.config.topics.task} (is the far end "
                    "dsteleop robot-sim?)"
                )
            time.sleep(0.005)
        with self._lock:
            self._events.clear()
        return X

    def _status_now(self) -> dict[str, Any] | None:
        with self._lock:
            return self._status

    def goal(self) -> HandState | None:
        st = self._status_now()
        return None if st is None or st["goal"] is None else state_from_json(st["goal"])

    def apply(self, X_next: HandState) -> PlantStep:
        now = self._now()
        self.robot.apply(X_next, self._seq, now)
        self._seq += 1
        state = self.robot.state(now)
        self._task_in.newest()  # raises on a wrong message
        assert state is not None  # reset waited for one
        with self._lock:
            events, self._events = tuple(self._events), []
            st = self._status
        assert st is not None
        outcome = None if st["outcome"] is None else Outcome(**st["outcome"])
        return PlantStep(
            X_current=state.X,
            phase=Phase(st["phase"]),
            events=events,
            outcome=outcome,
            robot_lost=self.robot.link_status(now),
        )

    def set_goal_noise(self, sigma_m: float) -> None:
        raise ConfigError("robot link: the far end draws the goals; restart it with --goal-noise")

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "zenoh",
            "utensil": self.utensil,
            "seed": self.seed,
            "control_dt_s": 1.0 / self.config.rate_hz,
            "link": self.config.to_json(),
        }

    def scene(self) -> SceneGeometry | None:
        return None

    def true_goals(self) -> tuple[HandState, HandState]:
        """The true pick and place palm poses, as the far end's world has them now."""
        st = self._status_now()
        assert st is not None
        pick, place = st["true_goals"]
        return state_from_json(pick), state_from_json(place)

    def close(self) -> None:
        self._task_in.close()
        self.robot.close()
