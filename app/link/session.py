"""Zenoh sessions, publishers and subscribers that speak ROS 2 the way rmw_zenoh does.

The one module of the link that imports `zenoh`. A `Topic` publishes one ROS 2 type on one
topic (key expression, CDR payload and attachment from `link.ros`); a `Subscription` keeps
only the newest message of a topic (a one-slot mailbox, like the loop's: a late reader gets
the newest state, never a queue of old ones) and records the first wrong message it sees
(another type on the topic, bytes that are not the type, a missing attachment) as an error
the reader raises.

A `Node` makes an end visible in a ROS 2 graph on rmw_zenoh: it declares the node's liveliness
token, and a `Topic` or `Subscription` given the node declares its own (keys from
`ros.liveliness_key`); each token is undeclared when its owner closes, and all of them vanish
with the session.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from dsteleop.app.link import ros
from dsteleop.app.link.config import Endpoints
from dsteleop.errors import InputError

T = TypeVar("T")


def open_session(ends: Endpoints, connect_timeout_s: float, who: str) -> Any:
    """A Zenoh peer session that listens and connects where `ends` says, and nowhere else
    (no multicast scouting: nothing leaves the given endpoints).

    Raises:
        InputError: a listen endpoint cannot be bound, or no connect endpoint answered within
            `connect_timeout_s` (one line: what, where, and the likely cause).
    """
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps(list(ends.listen)))
    c.insert_json5("listen/exit_on_failure", "true")
    c.insert_json5("connect/endpoints", json.dumps(list(ends.connect)))
    if ends.connect:
        c.insert_json5("connect/timeout_ms", str(max(1, round(connect_timeout_s * 1000))))
        c.insert_json5("connect/exit_on_failure", "true")
        # After the other end went away, retry every 0.1-0.5 s (not Zenoh's default 1-4 s),
        # so a restarted far end is picked up about as fast as it publishes.
        c.insert_json5(
            "connect/retry",
            '{"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}',
        )
    c.insert_json5("scouting/multicast/enabled", "false")
    try:
        return zenoh.open(c)
    except zenoh.ZError as exc:
        text = str(exc).split(" at ", 1)[0].strip().rstrip(".")
        if ends.connect and ("connect" in text.lower() or "timeout" in text.lower()):
            raise InputError(
                f"robot link ({who}): no answer from {', '.join(ends.connect)} within "
                f"{connect_timeout_s:g} s (is the other end running?)"
            ) from None
        where = ", ".join(ends.listen) or ", ".join(ends.connect)
        raise InputError(
            f"robot link ({who}): cannot open a Zenoh session on {where} ({text})"
        ) from None


class Node:
    """A ROS 2 node on a session: its liveliness token, and ids for its entities.

    As rmw_zenoh does, the node and its entities take ids from one counter per session: the
    node is 0 (its token carries 0 twice), its publishers and subscriptions 1, 2, ...

    Args:
        session: an open Zenoh session.
        domain_id: ROS_DOMAIN_ID.
        node: the node's name, namespace and enclave.
    """

    def __init__(self, session: Any, domain_id: int, node: ros.RosNode) -> None:
        self.session = session
        self.domain_id = domain_id
        self.node = node
        self.zid = str(session.zid())
        self.node_id = 0
        self._next_id = 1
        self.key = ros.liveliness_key(domain_id, self.zid, node, 0, 0, ros.NODE)
        self._token = session.liveliness().declare_token(self.key)

    def declare(self, kind: str, topic: str, ros_type: str) -> tuple[str, Any]:
        """Declare a publisher's or subscription's token: (its key, the token)."""
        eid, self._next_id = self._next_id, self._next_id + 1
        key = ros.liveliness_key(
            self.domain_id, self.zid, self.node, self.node_id, eid, kind, topic, ros_type
        )
        return key, self.session.liveliness().declare_token(key)

    def close(self) -> None:
        self._token.undeclare()


class Topic:
    """Publishes one ROS 2 type on one topic, each message with rmw_zenoh's attachment.

    Args:
        session: an open Zenoh session.
        domain_id: ROS_DOMAIN_ID.
        topic: the topic name.
        ros_type: e.g. `ros.POSE_STAMPED`.
        node: the node it belongs to, which declares its liveliness token (None: no token,
            invisible to ROS 2's graph, as for a test's probe).
    """

    def __init__(
        self,
        session: Any,
        domain_id: int,
        topic: str,
        ros_type: str,
        node: Node | None = None,
    ) -> None:
        import zenoh

        self.key = ros.key_expr(domain_id, topic, ros_type)
        self.ros_type = ros_type
        self.gid = ros.gid(str(session.zid()), topic)
        self._pub = session.declare_publisher(
            self.key,
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.REAL_TIME,
            express=True,
        )
        #: The key of its liveliness token (None without a node).
        self.token_key: str | None = None
        self._token: Any = None
        if node is not None:
            self.token_key, self._token = node.declare(ros.PUBLISHER, topic, ros_type)

    def put(self, payload: bytes, seq: int, stamp_ns: int) -> None:
        """Send one CDR payload with its sequence number and source stamp [ns, UNIX]."""
        att = ros.encode_attachment(ros.Attachment(seq, stamp_ns, self.gid))
        self._pub.put(payload, attachment=att)

    def close(self) -> None:
        if self._token is not None:
            self._token.undeclare()
        self._pub.undeclare()


@dataclass(frozen=True)
class Received(Generic[T]):
    """One decoded message.

    Attributes:
        msg: the decoded message.
        attachment: its sequence number, source stamp and publisher GID.
        t_recv_mono_s: when it arrived, on `time.monotonic` [s].
        t_recv_ns: when it arrived, on the UNIX clock [ns].
    """

    msg: T
    attachment: ros.Attachment
    t_recv_mono_s: float
    t_recv_ns: int


class Subscription(Generic[T]):
    """The newest message of one ROS 2 type on one topic (module docstring).

    It subscribes to every type on the topic, so a publisher of another type is seen and
    named rather than silently never matched.

    Args:
        session: an open Zenoh session.
        domain_id: ROS_DOMAIN_ID.
        topic: the topic name.
        ros_type: the expected type.
        decode: CDR bytes -> message (raises `InputError` on bytes that are not one).
        on_message: called with each good message, in Zenoh's thread (must not block).
        node: the node it belongs to, which declares its liveliness token (None: no token).
    """

    def __init__(
        self,
        session: Any,
        domain_id: int,
        topic: str,
        ros_type: str,
        decode: Callable[[bytes], T],
        on_message: Callable[[Received[T]], None] | None = None,
        node: Node | None = None,
    ) -> None:
        self.topic = topic
        self.ros_type = ros_type
        self._dds = ros.dds_type_name(ros_type)
        self._hash = ros.type_hash(ros_type)
        self._decode = decode
        self._on_message = on_message
        self._lock = threading.Lock()
        self._newest: Received[T] | None = None
        self._error: str | None = None
        self.count = 0
        self._sub = session.declare_subscriber(
            ros.topic_wildcard(domain_id, topic), self._on_sample
        )
        #: The key of its liveliness token (None without a node).
        self.token_key: str | None = None
        self._token: Any = None
        if node is not None:
            self.token_key, self._token = node.declare(ros.SUBSCRIPTION, topic, ros_type)

    def _on_sample(self, sample: Any) -> None:
        t_mono, t_ns = time.monotonic(), time.time_ns()
        try:
            dds, hsh = ros.type_of_key(str(sample.key_expr))
            if dds != self._dds:
                raise InputError(
                    f"robot link: topic {self.topic} carries {dds}, expected {self._dds} "
                    f"({self.ros_type})"
                )
            if hsh != self._hash:
                raise InputError(
                    f"robot link: topic {self.topic}: type hash {hsh} differs from "
                    f"{self.ros_type}'s {self._hash} (another definition of the type)"
                )
            att = sample.attachment
            attachment = ros.decode_attachment(None if att is None else att.to_bytes())
            msg = self._decode(sample.payload.to_bytes())
        except InputError as exc:
            with self._lock:
                if self._error is None:
                    self._error = str(exc)
            return
        rec = Received(msg, attachment, t_mono, t_ns)
        with self._lock:
            self._newest = rec
            self.count += 1
        if self._on_message is not None:
            self._on_message(rec)

    def newest(self) -> Received[T] | None:
        """The newest good message, or None before the first.

        Raises:
            InputError: a wrong message arrived on the topic (once seen, always raised).
        """
        with self._lock:
            if self._error is not None:
                raise InputError(self._error)
            return self._newest

    def close(self) -> None:
        if self._token is not None:
            self._token.undeclare()
        self._sub.undeclare()
