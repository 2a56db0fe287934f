"""The far end: the PyBullet robot behind the Zenoh link (`dsteleop robot-sim --zenoh CONFIG`).

The reference for a real arm's driver (docs/link.md): a robot driver and nothing else (the
task is judged at the near end, through a twin). It runs the link configuration's robot
(`LinkConfig.robot`, a description) as a `plants.simulated.SimulatedRobot` in a PyBullet world
of its own, the kitchen scene standing for what is in front of a real arm, in real time at
`rate_hz`, and:

    commands   each PoseStamped/JointState on the command topics is checked as it arrives:
               older than `command_timeout_s` (its source stamp against this clock) -> dropped
               as stale; a sequence number not above the last one of the same publisher ->
               dropped as out of order. A good one is applied at once (`set_target`); the
               applied-minus-published time is the link latency (`latencies_s`).
    watchdog   no good pose command for `command_timeout_s`: the robot halts, holding the
               palm pose measured at that moment (fingers hold their last openness), as MoveIt
               Servo halts when its commands stop. A fresh command resumes.
    state      after each physics step (1/rate_hz of simulated time): the measured palm pose,
               the description's joints (arm, then fingers: `joint_names_of`) and the
               fingers' openness, stamped and numbered. Before the first command the world
               stands still (published, not stepped), as the near end's twin does.

A stray message on a command topic (another type, bytes that are not the type, a cut
buffer, a missing attachment, a pose in another frame than `base_frame`, finger openness
without one of the robot's fingers) is dropped, counted and logged (`session.Subscription`:
the first of each reason at once, then at most a line per 5 s): in a ROS 2 graph anyone can
publish on a topic, so it is never fatal. The counts are in `summary()["dropped_stray"]`,
by topic and reason.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from dsteleop.app.link import ros
from dsteleop.app.link.config import LinkConfig
from dsteleop.app.link.session import Node, Received, Subscription, Topic, open_session

log = logging.getLogger(__name__)


#: The far end's node in a ROS 2 graph: /dsteleop_robot_sim (`ros2 node list`).
FAR_NODE = ros.RosNode("dsteleop_robot_sim")


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
        config: the link's configuration (its robot is the simulated arm).
        utensil: the utensil in the arm's world (the scene in front of it).

    Raises:
        InputError: the session cannot be opened, the robot's description does not load,
            or its arm cannot reach a pose of the task (`robot.reach.require_reachable`).
    """

    def __init__(self, config: LinkConfig, utensil: str = "spoon") -> None:
        from dsteleop.app.plants.simulated import SimulatedRobot
        from dsteleop.robot.reach import require_reachable

        self.config, desc = config.for_robot()
        # As `run` refuses it at the near end: an arm that cannot reach the task where its
        # scene stands is refused before the session opens (one line: the pose, the fix).
        require_reachable(desc)
        d, t = self.config.domain_id, self.config.topics
        # The session first: a bad endpoint fails before the simulation is built.
        self._session = open_session(self.config.far, self.config.connect_timeout_s, "far end")
        try:
            self.robot = SimulatedRobot.alone(desc, 1.0 / self.config.rate_hz, utensil=utensil)
            st = self.robot.reset(0.0)
        except BaseException:
            self._session.close()
            raise
        config = self.config
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
        #: The far end as a ROS 2 node in the graph (its liveliness tokens, docs/link.md).
        self.node = Node(self._session, d, FAR_NODE)
        self._pose_in: Subscription[ros.PoseMsg] = Subscription(
            self._session,
            d,
            t.command_pose,
            ros.POSE_STAMPED,
            ros.decode_pose,
            lambda r: self._offer(self._pose_slot, r),
            self.node,
            check=self._check_pose,
        )
        self._fingers_in: Subscription[ros.JointsMsg] = Subscription(
            self._session,
            d,
            t.command_fingers,
            ros.JOINT_STATE,
            ros.decode_joints,
            lambda r: self._offer(self._fingers_slot, r),
            self.node,
            check=self._check_fingers,
        )
        n = self.node
        self._pose_out = Topic(self._session, d, t.state_pose, ros.POSE_STAMPED, n)
        self._joints_out = Topic(self._session, d, t.state_joints, ros.JOINT_STATE, n)
        self._fingers_out = Topic(self._session, d, t.state_fingers, ros.JOINT_STATE, n)
        self._endpoints: tuple[Topic | Subscription[Any] | Node, ...] = (
            self._pose_in,
            self._fingers_in,
            self._pose_out,
            self._joints_out,
            self._fingers_out,
            self.node,  # last: its entities' tokens go first
        )
        self._seq = 0
        self._last_cmd_mono: float | None = None
        self._hold = (st.X.position.copy(), st.X.rotation.copy())
        self._openness = st.X.openness.copy()

    def _check_pose(self, msg: ros.PoseMsg) -> str | None:
        """Why a pose command is refused: another frame than `base_frame` (None: it is not)."""
        if msg.frame_id != self.config.base_frame:
            return f"pose in frame {msg.frame_id!r}, expected {self.config.base_frame!r}"
        return None

    def _check_fingers(self, msg: ros.JointsMsg) -> str | None:
        """Why a finger command is refused: one of the robot's fingers is missing."""
        missing = [f for f in self.config.finger_names if f not in msg.names]
        return f"lacks finger {missing[0]!r}" if missing else None

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

    def _apply_commands(self) -> None:
        fingers = self._take(self._fingers_slot)
        if fingers is not None:
            by_name = dict(zip(fingers.msg.names, fingers.msg.positions, strict=True))
            self._openness = np.clip([by_name[f] for f in self.config.finger_names], 0.0, 1.0)
        pose = self._take(self._pose_slot)
        if pose is None:
            if fingers is not None and not self.halted:
                self.robot.env.set_target(*self._hold, self._openness)
            return
        self._hold = (pose.msg.p_m, pose.msg.R)
        self.robot.env.set_target(pose.msg.p_m, pose.msg.R, self._openness)
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
        X = self.robot.env.state().palm
        self._hold = (X.position.copy(), X.rotation.copy())
        self.robot.env.set_target(*self._hold, self._openness)
        self.halted = True
        self.halt_reason = f"no command for {now_mono - last:.2f} s"
        log.warning("robot-sim: halted, %s (holding the palm where it is)", self.halt_reason)

    def _publish(self) -> None:
        st = self.robot.state(0.0)
        assert st is not None  # a simulated robot always has one
        stamp = time.time_ns()
        self._seq += 1
        t = self.config
        self._pose_out.put(
            ros.encode_pose(st.X.position, st.X.rotation, t.base_frame, stamp), self._seq, stamp
        )
        self._joints_out.put(
            ros.encode_joints(self.robot.joint_names, st.joints, stamp), self._seq, stamp
        )
        self._fingers_out.put(
            ros.encode_joints(t.finger_names, st.X.openness, stamp), self._seq, stamp
        )

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
            self._apply_commands()
            now = time.monotonic()
            self._watchdog(now)
            if now >= next_t:
                if self.applied:  # the world starts with the first command
                    self.robot.env.step_robot()
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
            "dropped_stray": self.dropped(),
            "latency_ms": {
                "p50": round(float(np.percentile(lat, 50)), 3) if lat.size else None,
                "p95": round(float(np.percentile(lat, 95)), 3) if lat.size else None,
                "p99": round(float(np.percentile(lat, 99)), 3) if lat.size else None,
                "max": round(float(lat.max()), 3) if lat.size else None,
                "n": int(lat.size),
            },
        }

    def dropped(self) -> dict[str, dict[str, int]]:
        """Stray messages dropped on each command topic, by reason (`Subscription.REASONS`)."""
        return {s.topic: s.dropped for s in (self._pose_in, self._fingers_in)}

    def close(self) -> None:
        for c in getattr(self, "_endpoints", ()):
            c.close()
        self._endpoints = ()
        self._session.close()
        self.robot.close()
