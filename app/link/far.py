"""The far end: the PyBullet robot behind the Zenoh link (`dsteleop robot-sim --zenoh CONFIG`).

The reference for a real arm's driver (docs/link.md). It runs the KUKA iiwa with its hand in
the kitchen (`robot.env.KitchenEnv`) in real time at `rate_hz`, and:

    commands   each PoseStamped/JointState on the command topics is checked as it arrives:
               older than `command_timeout_s` (its source stamp against this clock) -> dropped
               as stale; a sequence number not above the last one of the same publisher ->
               dropped as out of order. A good one is applied at once (`set_target`); the
               applied-minus-published time is the link latency (`latencies_s`).
    watchdog   no good pose command for `command_timeout_s`: the robot halts, holding the
               palm pose measured at that moment (fingers hold their last openness), as MoveIt
               Servo halts when its commands stop. A fresh command resumes.
    state      after each physics step (1/rate_hz of simulated time): the measured palm pose,
               every joint's position and the fingers' openness, stamped and numbered.
               Before the first command the world stands still (published, not stepped),
               so the kitchen task's clock starts when the near end does.

A wrong message on a command topic (another type, bytes that are not the type) stops it with
an `InputError` (one line, exit code 2).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from dsteleop.app.link import ros
from dsteleop.app.link.config import LinkConfig
from dsteleop.app.link.session import Received, Subscription, Topic, open_session
from dsteleop.arbitration import HandState
from dsteleop.errors import InputError

log = logging.getLogger(__name__)


def state_json(X: HandState) -> list[float]:
    """A hand state as 12 + F numbers: position, rotation row by row, openness."""
    return [float(v) for v in (*X.position, *np.ravel(X.rotation), *X.openness)]


def state_from_json(v: list[float]) -> HandState:
    """`state_json`'s inverse."""
    a = np.asarray(v, dtype=np.float64)
    return HandState(a[:3], a[3:12].reshape(3, 3), a[12:])


@dataclasses.dataclass
class _Slot:
    """The newest accepted command of one topic, and the sequence it belongs to."""

    gid: bytes = b""
    seq: int = -(2**63)
    rec: Received[Any] | None = None
    taken: bool = True


class FarEnd:
    """The simulated robot's side of the link (module docstring).

    Args:
        config: the link's configuration.
        utensil: the kitchen's utensil (the world the arm stands in).
        seed: the kitchen's seed (of the task's goal noise).
        goal_noise_m: std-dev of the task's goal position noise [m] (None: the task's).

    Raises:
        InputError: the session cannot be opened.
    """

    def __init__(
        self,
        config: LinkConfig,
        utensil: str = "spoon",
        seed: int = 0,
        goal_noise_m: float | None = None,
    ) -> None:
        from dsteleop.robot.arm import RobotConfig
        from dsteleop.robot.env import EnvConfig, KitchenEnv

        self.config = config
        d, t = config.domain_id, config.topics
        # The session first: a bad endpoint fails before the simulation is built.
        self._session = open_session(config.far, config.connect_timeout_s, "far end")
        try:
            env_config = EnvConfig(robot=RobotConfig.for_period(1.0 / config.rate_hz))
            if goal_noise_m is not None:
                task = dataclasses.replace(env_config.task, goal_noise_pos_m=float(goal_noise_m))
                env_config = dataclasses.replace(env_config, task=task)
            self.env = KitchenEnv(env_config)
        except BaseException:
            self._session.close()
            raise
        self.env.reset(utensil, seed)
        if len(config.finger_names) != len(self.env.robot.finger_names):
            self.close()
            raise InputError(
                f"robot-sim: the link names {len(config.finger_names)} fingers, the simulated "
                f"hand has {len(self.env.robot.finger_names)}"
            )
        self._wake = threading.Event()
        self._lock = threading.Lock()
        self._pose_slot = _Slot()
        self._fingers_slot = _Slot()
        self.dropped_stale = 0
        self.dropped_order = 0
        #: Published -> applied time of each applied pose command [s] (recent ones).
        self.latencies_s: deque[float] = deque(maxlen=100_000)
        self.applied = 0
        self.halted = True
        self.halt_reason = "waiting for commands"
        self._pose_in: Subscription[ros.PoseMsg] = Subscription(
            self._session,
            d,
            t.command_pose,
            ros.POSE_STAMPED,
            ros.decode_pose,
            lambda r: self._offer(self._pose_slot, r),
        )
        self._fingers_in: Subscription[ros.JointsMsg] = Subscription(
            self._session,
            d,
            t.command_fingers,
            ros.JOINT_STATE,
            ros.decode_joints,
            lambda r: self._offer(self._fingers_slot, r),
        )
        self._pose_out = Topic(self._session, d, t.state_pose, ros.POSE_STAMPED)
        self._joints_out = Topic(self._session, d, t.state_joints, ros.JOINT_STATE)
        self._fingers_out = Topic(self._session, d, t.state_fingers, ros.JOINT_STATE)
        self._task_out = Topic(self._session, d, t.task, ros.STRING)
        self._events: list[Any] = []
        self._endpoints: tuple[Topic | Subscription[Any], ...] = (
            self._pose_in,
            self._fingers_in,
            self._pose_out,
            self._joints_out,
            self._fingers_out,
            self._task_out,
        )
        self._seq = 0
        self._last_cmd_mono: float | None = None
        st = self.env.state()
        self._hold = (st.palm.position.copy(), st.palm.rotation.copy())
        self._openness = st.palm.openness.copy()

    def _offer(self, slot: _Slot, rec: Received[Any]) -> None:
        """Zenoh's thread: keep a command if it is fresh and in order (module docstring)."""
        a = rec.attachment
        with self._lock:
            if rec.t_recv_ns - a.stamp_ns > self.config.command_timeout_s * 1e9:
                self.dropped_stale += 1
                return
            if a.gid == slot.gid and a.seq <= slot.seq:
                self.dropped_order += 1
                return
            slot.gid, slot.seq, slot.rec, slot.taken = a.gid, a.seq, rec, False
        self._wake.set()

    def _take(self, slot: _Slot) -> Received[Any] | None:
        with self._lock:
            if slot.taken:
                return None
            slot.taken = True
            return slot.rec

    def _check_errors(self) -> None:
        self._pose_in.newest()  # raises InputError after a wrong message
        self._fingers_in.newest()

    def _apply_commands(self) -> None:
        fingers = self._take(self._fingers_slot)
        if fingers is not None:
            by_name = dict(zip(fingers.msg.names, fingers.msg.positions, strict=True))
            missing = [f for f in self.config.finger_names if f not in by_name]
            if missing:
                raise InputError(
                    f"robot-sim: {self.config.topics.command_fingers} lacks finger {missing[0]!r}"
                )
            self._openness = np.clip([by_name[f] for f in self.config.finger_names], 0.0, 1.0)
        pose = self._take(self._pose_slot)
        if pose is None:
            if fingers is not None and not self.halted:
                self.env.set_target(*self._hold, self._openness)
            return
        if pose.msg.frame_id != self.config.base_frame:
            raise InputError(
                f"robot-sim: command pose in frame {pose.msg.frame_id!r}, expected "
                f"{self.config.base_frame!r}"
            )
        self._hold = (pose.msg.p_m, pose.msg.R)
        self.env.set_target(pose.msg.p_m, pose.msg.R, self._openness)
        self.latencies_s.append(time.time_ns() * 1e-9 - pose.attachment.stamp_ns * 1e-9)
        self._last_cmd_mono = time.monotonic()
        self.applied += 1
        if self.halted:
            log.info("robot-sim: commands arrive; moving (after: %s)", self.halt_reason)
            self.halted, self.halt_reason = False, ""

    def _watchdog(self, now_mono: float) -> None:
        last = self._last_cmd_mono
        if self.halted or last is None or now_mono - last <= self.config.command_timeout_s:
            return
        st = self.env.state()
        self._hold = (st.palm.position.copy(), st.palm.rotation.copy())
        self.env.set_target(*self._hold, self._openness)
        self.halted = True
        self.halt_reason = f"no command for {now_mono - last:.2f} s"
        log.warning("robot-sim: halted, %s (holding the palm where it is)", self.halt_reason)

    def _publish(self) -> None:
        st = self.env.state()
        stamp = time.time_ns()
        self._seq += 1
        names = tuple(st.joint_positions_rad)
        q = np.array([st.joint_positions_rad[n] for n in names])
        t = self.config
        self._pose_out.put(
            ros.encode_pose(st.palm.position, st.palm.rotation, t.base_frame, stamp),
            self._seq,
            stamp,
        )
        self._joints_out.put(ros.encode_joints(names, q, stamp), self._seq, stamp)
        self._fingers_out.put(
            ros.encode_joints(t.finger_names, st.palm.openness, stamp), self._seq, stamp
        )
        self._task_out.put(ros.encode_string(json.dumps(self._task_status())), self._seq, stamp)

    def _task_status(self) -> dict[str, Any]:
        """The kitchen task as the near end's plant needs it (`link.plant`): phase, the
        known goal, the true goals (for the demo operator), this tick's events, outcome."""
        task = self.env.task
        pick = (*self.env.grasp_pose(), np.ones(len(self.config.finger_names)))
        place = (*task.place_true, np.ones(len(self.config.finger_names)))
        out = task.outcome
        return {
            "phase": task.phase.value,
            "t_s": self.env.robot.state_time_s,
            "goal": None if task.phase.value == "done" else state_json(task.goal),
            "true_goals": [state_json(HandState(*pick)), state_json(HandState(*place))],
            "events": [[e.kind.value, e.t_s, e.detail] for e in self.env.last_events],
            "outcome": None if out is None else dataclasses.asdict(out),
        }

    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        """Step and publish in real time until `stop` is set (or `duration_s` passed)."""
        period = 1.0 / self.config.rate_hz
        t_end = None if duration_s is None else time.monotonic() + duration_s
        next_t = time.monotonic()
        self._publish()
        while not stop.is_set():
            now = time.monotonic()
            if t_end is not None and now >= t_end:
                return
            deadline = next_t
            if not self.halted and self._last_cmd_mono is not None:
                # wake when the watchdog is due, not at the next tick after it
                deadline = min(deadline, self._last_cmd_mono + self.config.command_timeout_s)
            self._wake.wait(max(0.0, deadline - now) + 1e-4)
            self._wake.clear()
            self._check_errors()
            self._apply_commands()
            now = time.monotonic()
            self._watchdog(now)
            if now >= next_t:
                if self.applied:  # the world (and the task's clock) starts with the first command
                    self.env.step()
                self._publish()
                next_t += period
                if now - next_t > period:  # fell behind: re-anchor, do not catch up
                    next_t = now + period

    def summary(self) -> dict[str, Any]:
        """Counters, and the link latency so far: a pose command's source stamp (just before
        the near end published it) to the moment its target was set here [ms]."""
        lat = np.array(self.latencies_s) * 1e3
        return {
            "applied": self.applied,
            "dropped_stale": self.dropped_stale,
            "dropped_out_of_order": self.dropped_order,
            "halted": self.halted,
            "halt_reason": self.halt_reason,
            "latency_ms": {
                "p50": round(float(np.percentile(lat, 50)), 3) if lat.size else None,
                "p95": round(float(np.percentile(lat, 95)), 3) if lat.size else None,
                "p99": round(float(np.percentile(lat, 99)), 3) if lat.size else None,
                "max": round(float(lat.max()), 3) if lat.size else None,
                "n": int(lat.size),
            },
        }

    def close(self) -> None:
        for c in getattr(self, "_endpoints", ()):
            c.close()
        self._endpoints = ()
        self._session.close()
        self.env.close()
