"""The near end: a robot at the far end of a Zenoh link, as a `ports.Robot`.

The arm is the link configuration's robot description (`LinkConfig.robot`): its fingers,
its joints' order and, unless the file gives its own, its limits (`config.link_limits`).
`ZenohRobot.apply` clamps each tick's command into the robot's workspace and speed limits
(`RobotLimits.clamp`, from the last command it sent), then publishes it at once: the palm
pose as a geometry_msgs/PoseStamped, the finger openness as a sensor_msgs/JointState, both
stamped (header stamp and attachment: UNIX time [ns]) and numbered (the attachment's sequence
number is the loop's tick seq). `state` returns the newest measured palm pose, joints and
finger openness the far end published (the joints in `joint_names` order: the arm's, then
the fingers', as the kitchen task's twin takes them), stamped with their arrival on the
loop's clock: the loop treats a state older than 0.2 s (`ports.ROBOT_STALE_S`) as a lost
robot and halts (`link_status` says why, for tools). A stray message on a state topic
(another type, bytes that are not the type, a cut buffer, a pose in another frame than
`base_frame`, a JointState without one of the robot's joints or fingers) is dropped,
counted and logged (`session.Subscription`), never fatal: the newest good state stays the
newest (`dropped` has the counts, and `reset`'s timeout names the last drop).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.link import ros
from dsteleop.app.link.config import LinkConfig
from dsteleop.app.link.session import Node, Received, Subscription, Topic, open_session
from dsteleop.app.plants.described import joint_names_of, joint_units_of
from dsteleop.app.ports import ROBOT_LOST, ROBOT_STALE_S, RobotLimits, RobotState
from dsteleop.arbitration import HandState
from dsteleop.errors import InputError
from dsteleop.robot.scene import SceneGeometry

log = logging.getLogger(__name__)

#: The near end's node in a ROS 2 graph: /dsteleop (`ros2 node list`).
NEAR_NODE = ros.RosNode("dsteleop")


class ZenohRobot:
    """A robot driven over Zenoh (module docstring).

    Args:
        config: the link's configuration (endpoints, topics, the robot, limits, timeouts).

    Raises:
        InputError: the session cannot be opened (no far end at the endpoint, a port in use),
            or the robot's description does not load.
        ConfigError: the configuration's finger names are not the description's.
    """

    def __init__(self, config: LinkConfig) -> None:
        self.config, self.desc = config.for_robot()
        assert self.config.limits is not None  # for_robot filled it in
        self._limits = self.config.limits
        self._joint_names = joint_names_of(self.desc)
        self._joint_units = joint_units_of(self.desc)
        config = self.config
        d, t = config.domain_id, config.topics
        self._session = open_session(config.near, config.connect_timeout_s, "near end")
        s = self._session
        #: The near end as a ROS 2 node in the graph (its liveliness tokens, docs/link.md).
        self.node = Node(s, d, NEAR_NODE)
        n = self.node
        self._pose_out = Topic(s, d, t.command_pose, ros.POSE_STAMPED, n)
        self._fingers_out = Topic(s, d, t.command_fingers, ros.JOINT_STATE, n)
        self._pose_in: Subscription[ros.PoseMsg] = Subscription(
            s, d, t.state_pose, ros.POSE_STAMPED, ros.decode_pose, node=n, check=self._check_pose
        )
        self._joints_in: Subscription[ros.JointsMsg] = Subscription(
            s,
            d,
            t.state_joints,
            ros.JOINT_STATE,
            ros.decode_joints,
            node=n,
            check=lambda m: _lacks(m, self._joint_names, "joint", f" of robot {self.desc.name}"),
        )
        self._fingers_in: Subscription[ros.JointsMsg] = Subscription(
            s,
            d,
            t.state_fingers,
            ros.JOINT_STATE,
            ros.decode_joints,
            node=n,
            check=lambda m: _lacks(m, self.config.finger_names, "finger"),
        )
        self._X_sent: HandState | None = None
        self._t_sent_s: float | None = None
        #: The last command as sent (after the clamp), for tests and benchmarks.
        self.last_sent: HandState | None = None
        self.sent = 0

    def _check_pose(self, msg: ros.PoseMsg) -> str | None:
        """Why a palm pose is refused: another frame than `base_frame` (None: it is not)."""
        if msg.frame_id != self.config.base_frame:
            return (
                f"palm pose in frame {msg.frame_id!r}, expected {self.config.base_frame!r} "
                "(base_frame)"
            )
        return None

    @property
    def dropped(self) -> dict[str, dict[str, int]]:
        """Stray messages dropped on each state topic, by reason (`Subscription.REASONS`)."""
        return {s.topic: s.dropped for s in self._subscriptions}

    @property
    def _subscriptions(self) -> tuple[Subscription[Any], ...]:
        return (self._pose_in, self._joints_in, self._fingers_in)

    # --- Robot -------------------------------------------------------------------------

    @property
    def name(self) -> str:
        return f"zenoh:{self.desc.name}"

    @property
    def finger_names(self) -> tuple[str, ...]:
        return self.config.finger_names

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The description's joints (`joint_names_of`): the arm's, then the fingers'."""
        return self._joint_names

    @property
    def joint_units(self) -> tuple[str, ...]:
        """Each joint's unit (`joint_units_of`): "rad", or "m" for a prismatic joint."""
        return self._joint_units

    @property
    def limits(self) -> RobotLimits:
        return self._limits

    def reset(self, now_s: float) -> RobotState:
        """Wait for the far end's state and return it.

        A linked robot is not teleported: it stays where it stands (its driver owns homing;
        `robot-sim` starts at the home pose), and the next command starts from there.

        Raises:
            InputError: no state within `connect_timeout_s` (naming the last stray message
                dropped, if any).
        """
        t0 = time.monotonic()
        while True:
            st = self.state(now_s + time.monotonic() - t0)
            if (
                st is not None
                and self._fingers_in.newest() is not None
                and self._joints_in.newest() is not None
            ):
                break
            if time.monotonic() - t0 > self.config.connect_timeout_s:
                drops = [s.last_drop for s in self._subscriptions if s.last_drop]
                why = f"dropped: {drops[-1]}" if drops else "is the far end running?"
                raise InputError(
                    f"robot link: no robot state on {self.config.topics.state_pose} within "
                    f"{self.config.connect_timeout_s:g} s ({why})"
                )
            time.sleep(0.005)
        self._X_sent, self._t_sent_s = st.X, None
        return st

    def apply(self, X_cmd: HandState, seq: int, now_s: float) -> None:
        """Clamp to the limits and publish (module docstring); returns at once."""
        if X_cmd.n_fingers != len(self.finger_names):
            raise InputError(
                f"robot link: {X_cmd.n_fingers} finger values for {len(self.finger_names)} fingers"
            )
        period = 1.0 / self.config.rate_hz
        if self._X_sent is None:
            st = self.state(now_s)
            if st is None:
                raise InputError("robot link: a command before any robot state (call reset first)")
            self._X_sent = st.X
        # The speed limit holds over the time since the last command, at most two periods: a
        # command after a pause does not get the whole pause's distance at once.
        dt = (
            period if self._t_sent_s is None else min(max(now_s - self._t_sent_s, 1e-3), 2 * period)
        )
        X = self.limits.clamp(self._X_sent, X_cmd, dt)
        stamp_ns = time.time_ns()
        self._pose_out.put(
            ros.encode_pose(X.position, X.rotation, self.config.base_frame, stamp_ns), seq, stamp_ns
        )
        self._fingers_out.put(
            ros.encode_joints(self.finger_names, X.openness, stamp_ns), seq, stamp_ns
        )
        self._X_sent, self._t_sent_s, self.last_sent = X, now_s, X
        self.sent += 1

    def state(self, now_s: float) -> RobotState | None:
        """The newest measured state, stamped on the loop's clock (its arrival); None before
        the first."""
        pose = self._pose_in.newest()
        joints = self._joints_in.newest()
        fingers = self._fingers_in.newest()
        if pose is None:
            return None
        q = self._joints(joints)
        g = self._openness(fingers)
        age_s = time.monotonic() - pose.t_recv_mono_s
        return RobotState(HandState(pose.msg.p_m, pose.msg.R, g), q, now_s - age_s)

    def _joints(self, joints: Received[ros.JointsMsg] | None) -> NDArray[np.float64]:
        """The measured joints in `joint_names` order (NaN before the first JointState)."""
        if joints is None:
            return np.full(len(self._joint_names), np.nan)
        by_name = dict(zip(joints.msg.names, joints.msg.positions, strict=True))
        return np.array([by_name[j] for j in self._joint_names], dtype=np.float64)

    def _openness(self, fingers: Received[ros.JointsMsg] | None) -> NDArray[np.float64]:
        if fingers is None:
            sent = self._X_sent
            return np.ones(len(self.finger_names)) if sent is None else sent.openness.copy()
        by_name = dict(zip(fingers.msg.names, fingers.msg.positions, strict=True))
        return np.clip(np.array([by_name[f] for f in self.finger_names]), 0.0, 1.0)

    def link_status(self, now_s: float) -> str:
        """ "" while the state is fresh by the loop's rule (`ports.ROBOT_STALE_S`), else why
        not ("robot lost: no state for 0.4 s"): the loop's verdict, for tools and tests."""
        st = self.state(now_s)
        if st is None:
            return f"{ROBOT_LOST}: no state yet"
        age = now_s - st.stamp_s
        return "" if age <= ROBOT_STALE_S else f"{ROBOT_LOST}: no state for {age:.1f} s"

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "zenoh",
            "name": self.desc.name,
            "description": self.desc.to_dict(),
            "link": self.config.to_json(),
        }

    def scene(self) -> SceneGeometry | None:
        return None

    def close(self) -> None:
        dropped = {t: n for t, d in self.dropped.items() if (n := sum(d.values()))}
        if dropped:
            log.warning("robot link: stray messages dropped on the state topics: %s", dropped)
        for c in (
            self._pose_out,
            self._fingers_out,
            self._pose_in,
            self._joints_in,
            self._fingers_in,
            self.node,
        ):
            c.close()
        self._session.close()


def _lacks(msg: ros.JointsMsg, names: Sequence[str], kind: str, of: str = "") -> str | None:
    """Why a JointState is refused: it lacks one of `names` (None: it has them all)."""
    missing = [n for n in names if n not in msg.names]
    return f"lacks {kind} {missing[0]!r}{of}" if missing else None
