"""ROS 2 on the wire, as a node on rmw_zenoh sends and receives it (docs/link.md).

Everything here is pure (bytes in, bytes out; no session, no clock):

    key expression   <domain_id>/<fully qualified topic, no leading '/'>/<DDS type name>/<type
                     hash>, e.g. 0/dsteleop/palm_pose_command/
                     geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3...
    payload          the message in CDR with its 4-byte encapsulation header (little endian:
                     00 01 00 00), from the ROS 2 type definitions `rosbags` ships
                     (Stores.ROS2_JAZZY)
    attachment       33 bytes: sequence number (int64 LE), source timestamp (int64 LE, ns
                     since the UNIX epoch), 0x10 (the GID's length), the 16-byte publisher GID

The type hash is REP-2016's RIHS01 of the type description, computed by rosbags.

Graph presence (`liveliness_key`): rmw_zenoh declares one Zenoh liveliness token per node,
publisher and subscription, whose key expression describes the entity:

    @ros2_lv/<domain_id>/<session zid>/<node id>/<entity id>/<NN|MP|MS>/<enclave>/<namespace>/
    <node name>[/<topic>/<DDS type name>/<type hash>/<qos>]

with every name mangled ("/" -> "%") and the QoS in rmw_zenoh's compact form (`qos_key`).
Followed: ros2/rmw_zenoh, rmw_zenoh_cpp/src/detail/liveliness_utils.cpp at 3411fdec and
docs/design.md ("Graph Cache") at 99a6a2bd.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import matrix_from_quat_wxyz, quat_wxyz_from_matrix
from dsteleop.errors import ContractError, InputError

Array = NDArray[np.float64]

POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
JOINT_STATE = "sensor_msgs/msg/JointState"
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
CDR_LE_HEADER = b"\x00\x01\x00\x00"
CDR_BE_HEADER = b"\x00\x00\x00\x00"


@cache
def typestore() -> Any:
    """The ROS 2 (Jazzy) type store of rosbags: message classes, CDR, type hashes."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def dds_type_name(ros_type: str) -> str:
    """The DDS name of a ROS 2 type: geometry_msgs/msg/PoseStamped ->
    geometry_msgs::msg::dds_::PoseStamped_ (what rmw_zenoh puts in its key expressions)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


@cache
def type_hash(ros_type: str) -> str:
    """REP-2016 type hash of a ROS 2 type ("RIHS01_" + 64 hex digits)."""
    return str(typestore().hash_rihs01(ros_type))


def key_expr(domain_id: int, topic: str, ros_type: str) -> str:
    """rmw_zenoh's key expression of a topic and its type (module docstring).

    Args:
        domain_id: ROS_DOMAIN_ID (0-232 in practice).
        topic: the fully qualified topic name, with or without the leading "/".
        ros_type: e.g. "geometry_msgs/msg/PoseStamped".
    """
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash(ros_type)}"


def topic_wildcard(domain_id: int, topic: str) -> str:
    """Every type on a topic: a subscriber on it sees a wrong-typed publisher too."""
    return f"{domain_id}/{topic.strip('/')}/*/*"


#: The admin space of rmw_zenoh's liveliness tokens.
LIVELINESS_PREFIX = "@ros2_lv"
#: Entity kinds in a liveliness key (rmw_zenoh also has SS and SC: services, unused here).
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"

# rmw/types.h enumerators, as rmw_zenoh writes them (std::to_string of the enum).
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2
LIVELINESS_AUTOMATIC = 1
#: RMW_DURATION_INFINITE (rmw/time.h): (sec, nsec) = (9223372036, 854775807), INT64_MAX ns.
DURATION_INFINITE = (9223372036, 854775807)


@dataclass(frozen=True)
class QoS:
    """A ROS 2 QoS profile as rmw_zenoh encodes it in a liveliness key (rmw/types.h values).

    The defaults are rmw_zenoh's own default profile (rmw_zenoh_cpp/src/detail/qos.cpp):
    reliable, volatile, keep last 42, infinite deadline, lifespan and lease, automatic
    liveliness; a field equal to its default is written as nothing.

    Attributes:
        reliability: RELIABLE or BEST_EFFORT.
        durability: VOLATILE or TRANSIENT_LOCAL.
        history: KEEP_LAST or KEEP_ALL.
        depth: the history depth [messages].
        deadline: (sec, nsec).
        lifespan: (sec, nsec).
        liveliness: LIVELINESS_AUTOMATIC (1) or another rmw liveliness policy.
        lease: the liveliness lease duration (sec, nsec).
    """

    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = 42
    deadline: tuple[int, int] = DURATION_INFINITE
    lifespan: tuple[int, int] = DURATION_INFINITE
    liveliness: int = LIVELINESS_AUTOMATIC
    lease: tuple[int, int] = DURATION_INFINITE


#: The link's QoS, declared for each of its publishers and subscriptions: best effort (its
#: publishers drop rather than block under congestion), volatile, keep last 1 (a
#: subscription keeps only the newest message).
LINK_QOS = QoS(reliability=BEST_EFFORT, depth=1)


def qos_key(qos: QoS) -> str:
    """rmw_zenoh's compact QoS chunk (`qos_to_keyexpr`): ":"-separated reliability,
    durability, "history,depth", "deadline s,ns", "lifespan s,ns" and "liveliness,lease s,ns",
    each field left empty where it equals rmw_zenoh's default (`QoS()`).
    E.g. the default profile is "::,:,:,:,,"; `LINK_QOS` is "2::,1:,:,:,,".
    """
    d = QoS()

    def f(v: int, default: int) -> str:
        return "" if v == default else str(v)

    return ":".join(
        (
            f(qos.reliability, d.reliability),
            f(qos.durability, d.durability),
            f"{f(qos.history, d.history)},{f(qos.depth, d.depth)}",
            f"{f(qos.deadline[0], d.deadline[0])},{f(qos.deadline[1], d.deadline[1])}",
            f"{f(qos.lifespan[0], d.lifespan[0])},{f(qos.lifespan[1], d.lifespan[1])}",
            f"{f(qos.liveliness, d.liveliness)},{f(qos.lease[0], d.lease[0])},"
            f"{f(qos.lease[1], d.lease[1])}",
        )
    )


def mangle(name: str) -> str:
    """A ROS name as one key chunk: every "/" becomes "%" (rmw_zenoh's `mangle_name`)."""
    return name.replace("/", "%")


@dataclass(frozen=True)
class RosNode:
    """A ROS 2 node's identity in the graph.

    Attributes:
        name: the node name (no "/").
        namespace: the node's namespace, "/" for none.
        enclave: the SROS enclave, "/" for none.
    """

    name: str
    namespace: str = "/"
    enclave: str = "/"


def liveliness_key(
    domain_id: int,
    zid: str,
    node: RosNode,
    node_id: int,
    entity_id: int,
    kind: str,
    topic: str | None = None,
    ros_type: str | None = None,
    qos: QoS = LINK_QOS,
) -> str:
    """The key expression of an entity's liveliness token (module docstring).

    Args:
        domain_id: ROS_DOMAIN_ID.
        zid: the Zenoh session id as Zenoh prints it (`str(session.zid())`).
        node: the node the entity belongs to.
        node_id: the node's id within its session (rmw_zenoh: a context-wide counter).
        entity_id: the entity's id (for the node itself: `node_id`).
        kind: NODE, PUBLISHER or SUBSCRIPTION.
        topic: the fully qualified topic name (publishers and subscriptions only).
        ros_type: e.g. "geometry_msgs/msg/PoseStamped" (with `topic`).
        qos: the entity's QoS (with `topic`).
    """
    if kind not in (NODE, PUBLISHER, SUBSCRIPTION):
        raise ContractError(f"liveliness_key: unknown entity kind {kind!r}")
    if (kind == NODE) != (topic is None) or (topic is None) != (ros_type is None):
        raise ContractError(
            "liveliness_key: a node has no topic; a publisher or subscription has one"
        )
    chunks = [
        LIVELINESS_PREFIX,
        str(domain_id),
        zid,
        str(node_id),
        str(entity_id),
        kind,
        mangle(node.enclave),
        mangle(node.namespace),
        mangle(node.name),
    ]
    if topic is not None and ros_type is not None:
        fq = topic if topic.startswith("/") else "/" + topic
        chunks += [mangle(fq), mangle(dds_type_name(ros_type)), type_hash(ros_type), qos_key(qos)]
    return "/".join(chunks)


def type_of_key(key: str) -> tuple[str, str]:
    """(DDS type name, type hash) of a received key expression (its last two chunks)."""
    parts = key.rsplit("/", 2)
    if len(parts) != 3:
        raise InputError(f"robot link: key expression {key!r} names no ROS 2 type")
    return parts[1], parts[2]


def gid(*parts: str) -> bytes:
    """A 16-byte publisher GID from stable names (the session id and the topic)."""
    return hashlib.sha256("/".join(parts).encode()).digest()[:GID_SIZE]


@dataclass(frozen=True)
class Attachment:
    """rmw_zenoh's per-message attachment.

    Attributes:
        seq: the publisher's sequence number.
        stamp_ns: source timestamp [ns since the UNIX epoch].
        gid: the publisher's 16-byte GID.
    """

    seq: int
    stamp_ns: int
    gid: bytes


def encode_attachment(a: Attachment) -> bytes:
    """The 33 attachment bytes (module docstring)."""
    if len(a.gid) != GID_SIZE:
        raise InputError(f"robot link: a GID has {GID_SIZE} bytes, got {len(a.gid)}")
    return struct.pack("<qqB", a.seq, a.stamp_ns, GID_SIZE) + bytes(a.gid)


def decode_attachment(data: bytes | None) -> Attachment:
    """Read an attachment; a missing or malformed one is an `InputError`."""
    if data is None:
        raise InputError("robot link: a message without its attachment (sequence number, stamp)")
    if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
        raise InputError(
            f"robot link: malformed attachment ({len(data)} bytes, expected {ATTACHMENT_SIZE})"
        )
    seq, stamp_ns, _ = struct.unpack_from("<qqB", data)
    return Attachment(int(seq), int(stamp_ns), bytes(data[17:]))


def _time(stamp_ns: int) -> Any:
    T = typestore().types["builtin_interfaces/msg/Time"]
    return T(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def _header(stamp_ns: int, frame_id: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_time(stamp_ns), frame_id=frame_id)


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def encode_pose(p_m: Array, R: Array, frame_id: str, stamp_ns: int) -> bytes:
    """A geometry_msgs/PoseStamped in CDR: position [m] and R as a quaternion (x, y, z, w)."""
    ts = typestore().types
    w, x, y, z = (float(v) for v in quat_wxyz_from_matrix(np.asarray(R, dtype=np.float64)))
    msg = ts[POSE_STAMPED](
        header=_header(stamp_ns, frame_id),
        pose=ts["geometry_msgs/msg/Pose"](
            position=ts["geometry_msgs/msg/Point"](
                x=float(p_m[0]), y=float(p_m[1]), z=float(p_m[2])
            ),
            orientation=ts["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        ),
    )
    return bytes(typestore().serialize_cdr(msg, POSE_STAMPED))


@dataclass(frozen=True)
class PoseMsg:
    """A decoded PoseStamped: position [m], rotation matrix, frame, header stamp [ns]."""

    p_m: Array
    R: Array
    frame_id: str
    stamp_ns: int


@dataclass(frozen=True)
class JointsMsg:
    """A decoded JointState: names, positions (radians, metres, or openness), stamp [ns]."""

    names: tuple[str, ...]
    positions: Array
    stamp_ns: int


def _deserialize(data: bytes, ros_type: str) -> Any:
    if data[:4] not in (CDR_LE_HEADER, CDR_BE_HEADER):
        raise InputError(
            f"robot link: not a CDR {ros_type} (encapsulation header {data[:4].hex() or 'none'})"
        )
    try:
        return typestore().deserialize_cdr(data, ros_type)
    except Exception as exc:  # rosbags raises SerdeError, struct.error, UnicodeDecodeError...
        raise InputError(f"robot link: not a CDR {ros_type} ({exc})") from None


def decode_pose(data: bytes) -> PoseMsg:
    """Read a PoseStamped; bytes that are not one are an `InputError`."""
    msg = _deserialize(data, POSE_STAMPED)
    o, pos = msg.pose.orientation, msg.pose.position
    q = np.array([o.w, o.x, o.y, o.z], dtype=np.float64)
    p = np.array([pos.x, pos.y, pos.z], dtype=np.float64)
    n = float(np.sqrt((q * q).sum()))
    if not (np.isfinite(p).all() and np.isfinite(q).all()) or abs(n - 1.0) > 1e-3:
        raise InputError(f"robot link: invalid pose (position {p.tolist()}, quaternion norm {n})")
    return PoseMsg(p, matrix_from_quat_wxyz(q), str(msg.header.frame_id), _stamp_ns(msg.header))


def encode_joints(names: tuple[str, ...], positions: Array, stamp_ns: int) -> bytes:
    """A sensor_msgs/JointState in CDR (positions only; velocity and effort empty)."""
    pos = np.asarray(positions, dtype=np.float64)
    if pos.shape != (len(names),):
        raise InputError(f"robot link: {len(names)} joint names but {pos.shape} positions")
    msg = typestore().types[JOINT_STATE](
        header=_header(stamp_ns, ""),
        name=list(names),
        position=pos.copy(),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )
    return bytes(typestore().serialize_cdr(msg, JOINT_STATE))


def decode_joints(data: bytes) -> JointsMsg:
    """Read a JointState; bytes that are not one are an `InputError`."""
    msg = _deserialize(data, JOINT_STATE)
    pos = np.asarray(msg.position, dtype=np.float64)
    if pos.shape != (len(msg.name),) or not np.isfinite(pos).all():
        raise InputError(
            f"robot link: invalid JointState ({len(msg.name)} names, {pos.size} positions)"
        )
    return JointsMsg(tuple(str(n) for n in msg.name), pos, _stamp_ns(msg.header))
