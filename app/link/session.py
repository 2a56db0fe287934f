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
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from dsteleop.app.link import ros
from dsteleop.app.link.config import Endpoints
from dsteleop.errors import InputError

log = logging.getLogger(__name__)

T = TypeVar("T")

#: After the first drop of each reason, a subscription logs its drops at most this often [s].
DROP_LOG_PERIOD_S = 5.0


def session_mode(ends: Endpoints) -> str:
    """ "peer" for an end that listens, "client" for one that only connects (module
    docstring: peers that do not listen get nothing through a router)."""
    return "peer" if ends.listen else "client"


def open_session(ends: Endpoints, connect_timeout_s: float, who: str) -> Any:
    """A Zenoh session that listens and connects where `ends` says, and nowhere else (no
    multicast scouting: nothing leaves the given endpoints): a peer if it listens, else a
    client (`session_mode`).

    Raises:
        InputError: a listen endpoint cannot be bound, or no connect endpoint answered within
            `connect_timeout_s` (one line: what, where, and the likely cause).
    """
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(session_mode(ends)))
    if ends.listen:
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

    It subscribes to every type on the topic, so a publisher of another type is seen, named
    and dropped rather than silently never matched.

    Args:
        session: an open Zenoh session.
        domain_id: ROS_DOMAIN_ID.
        topic: the topic name.
        ros_type: the expected type.
        decode: CDR bytes -> message (raises `InputError` on bytes that are not one).
        on_message: called with each good message, in Zenoh's thread (must not block).
        node: the node it belongs to, which declares its liveliness token (None: no token).
        check: a decoded message -> why it is refused ("" or None: accepted), e.g. a pose in
            another frame; a refused message is dropped as "refused".
    """

    #: The reasons a message is dropped, the keys of `dropped`.
    REASONS = ("wrong_type", "bad_attachment", "bad_payload", "refused")

    def __init__(
        self,
        session: Any,
        domain_id: int,
        topic: str,
        ros_type: str,
        decode: Callable[[bytes], T],
        on_message: Callable[[Received[T]], None] | None = None,
        node: Node | None = None,
        check: Callable[[T], str | None] | None = None,
    ) -> None:
        self.topic = topic
        self.ros_type = ros_type
        self._dds = ros.dds_type_name(ros_type)
        self._hash = ros.type_hash(ros_type)
        self._decode = decode
        self._check = check
        self._on_message = on_message
        self._lock = threading.Lock()
        self._newest: Received[T] | None = None
        self.count = 0
        self._dropped = dict.fromkeys(self.REASONS, 0)
        #: The newest drop's one-line reason ("" before any).
        self.last_drop = ""
        self._logged: set[str] = set()
        self._t_log = -float("inf")
        self._unlogged = 0
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
        reason = "wrong_type"
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
            reason = "bad_attachment"
            att = sample.attachment
            attachment = ros.decode_attachment(None if att is None else att.to_bytes())
            reason = "bad_payload"
            msg = self._decode(sample.payload.to_bytes())
            reason = "refused"
            why = self._check(msg) if self._check is not None else None
            if why:
                raise InputError(f"robot link: topic {self.topic}: {why}")
        except InputError as exc:
            self._drop(reason, str(exc), t_mono)
            return
        rec = Received(msg, attachment, t_mono, t_ns)
        with self._lock:
            self._newest = rec
            self.count += 1
        if self._on_message is not None:
            self._on_message(rec)

    def _drop(self, reason: str, text: str, t_mono: float) -> None:
        """Count a dropped message; log it if it is the first of its reason or the last line
        is `DROP_LOG_PERIOD_S` old (with the drops since), else only count it."""
        with self._lock:
            self._dropped[reason] += 1
            self.last_drop = text
            first = reason not in self._logged
            if not first and t_mono - self._t_log < DROP_LOG_PERIOD_S:
                self._unlogged += 1
                return
            self._logged.add(reason)
            since, self._unlogged, self._t_log = self._unlogged, 0, t_mono
            total = sum(self._dropped.values())
        more = f"; {since} more since the last line" if since else ""
        log.warning("%s: dropped (%d on this topic so far%s)", text, total, more)

    @property
    def dropped(self) -> dict[str, int]:
        """How many messages were dropped, by reason (`REASONS`)."""
        with self._lock:
            return dict(self._dropped)

    def newest(self) -> Received[T] | None:
        """The newest good message, or None before the first."""
        with self._lock:
            return self._newest

    def close(self) -> None:
        if self._token is not None:
            self._token.undeclare()
        self._sub.undeclare()
