"""An outside ROS 2 client of the robot link, run by tests/test_link_ros2_client.py with the
Python of a virtual environment of its own (never dsteleop's): it imports nothing of dsteleop.

The client is zenoh-ros2-sdk (PyPI), a ROS 2-over-Zenoh library written apart from dsteleop:
its own RIHS01 type hashes (computed from the .msg definitions below), its own rmw_zenoh key
expressions, liveliness tokens and attachments, and its own session (rmw_zenoh's default
session configuration: a peer that listens on localhost and connects to the router). Its CDR
is rosbags' (the library dsteleop uses too), so every payload is also read and written here
with a second, independent CDR implementation, mcap-ros2-support's (Foxglove's), and the two
compared.

What it does, as a ROS 2 tool or node would (one JSON line on stdout):

1. discovery: the topics and their types, and each topic's publishers and subscriptions
   with their node names (`ros2 topic list -t`, `ros2 topic info -v`);
2. state: subscribes to the palm pose, the finger state and the joint states for
   `--listen-s` seconds, counting them and decoding each pose twice (the SDK's and
   mcap-ros2-support's CDR);
3. commands: publishes palm pose commands `--offset-m` to the side of the pose it measured
   and a finger command, at 30 Hz for `--command-s` seconds, and reads back where the palm
   and fingers went.

The message definitions are ROS 2 Jazzy's (common_interfaces, rcl_interfaces), comments left
out; the SDK's registry reads them from `--msgs`, so it never downloads definitions.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import logging
import struct
import threading
import time
from pathlib import Path
from typing import Any

DEFINITIONS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n"
    ),
}
POSE, JOINTS = "geometry_msgs/msg/PoseStamped", "sensor_msgs/msg/JointState"
#: mcap-ros2-support's concatenated schema of each type (the type, then its dependencies).
SCHEMAS = {
    POSE: [
        "std_msgs/msg/Header",
        "geometry_msgs/msg/Pose",
        "geometry_msgs/msg/Point",
        "geometry_msgs/msg/Quaternion",
    ],
    JOINTS: ["std_msgs/msg/Header"],
}


def schema(ros_type: str) -> str:
    parts = [DEFINITIONS[ros_type]]
    for dep in SCHEMAS[ros_type]:
        pkg, _, name = dep.split("/")
        parts.append("=" * 80 + f"\nMSG: {pkg}/{name}\n" + DEFINITIONS[dep])
    return "".join(parts)


def write_definitions(folder: Path) -> None:
    for ros_type, text in DEFINITIONS.items():
        pkg, kind, name = ros_type.split("/")
        (folder / pkg / kind).mkdir(parents=True, exist_ok=True)
        (folder / pkg / kind / f"{name}.msg").write_text(text)


def offline(*args: Any, **kwargs: Any) -> Any:
    raise RuntimeError("outside client: message definitions are read from --msgs only")


def pose_of(msg: Any) -> dict[str, Any]:
    """A PoseStamped as plain numbers (works for both libraries' message objects)."""
    p, q, h = msg.pose.position, msg.pose.orientation, msg.header
    return {
        "p_m": [float(p.x), float(p.y), float(p.z)],
        "q_xyzw": [float(q.x), float(q.y), float(q.z), float(q.w)],
        "frame_id": str(h.frame_id),
        "stamp_ns": int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec),
    }


class Recorder:
    """Every message of one topic, with when it arrived."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: list[tuple[float, Any]] = []

    def __call__(self, msg: Any) -> None:
        with self.lock:
            self.items.append((time.monotonic(), msg))

    def since(self, t: float) -> list[tuple[float, Any]]:
        with self.lock:
            return [(ti, m) for ti, m in self.items if ti >= t]

    def newest(self) -> Any:
        with self.lock:
            return self.items[-1][1] if self.items else None


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--router", required=True, help="host:port of the Zenoh router (or peer)")
    ap.add_argument("--msgs", required=True, type=Path)
    ap.add_argument("--listen-s", type=float, default=3.0)
    ap.add_argument("--command-s", type=float, default=3.0)
    ap.add_argument("--offset-m", type=float, default=0.05)
    ap.add_argument("--openness", type=float, default=0.3)
    ap.add_argument("--discovery-timeout-s", type=float, default=20.0)
    args = ap.parse_args()
    host, port = args.router.rsplit(":", 1)
    where = {"router_ip": host, "router_port": int(port)}

    write_definitions(args.msgs)
    from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic
    from zenoh_ros2_sdk import (
        ROS2Publisher,
        ROS2Subscriber,
        get_registry,
        get_topic_info,
        get_topic_names_and_types,
        message_registry,
    )

    get_registry(str(args.msgs))  # the first call names the registry's folder
    message_registry.get_message_file_path = offline
    message_registry.clone_to_cache = offline
    out: dict[str, Any] = {"sdk": importlib.metadata.version("zenoh-ros2-sdk")}

    # 1. discovery
    ours = {
        "/dsteleop/palm_pose_command": POSE,
        "/dsteleop/finger_command": JOINTS,
        "/dsteleop/palm_pose": POSE,
        "/dsteleop/joint_states": JOINTS,
        "/dsteleop/finger_state": JOINTS,
    }
    t_end = time.monotonic() + args.discovery_timeout_s
    while True:
        topics = dict(get_topic_names_and_types(domain_id=0, timeout=1.0, **where))
        infos = {
            t: get_topic_info(t, domain_id=0, timeout=1.0, verbose=True, **where) for t in ours
        }
        complete = all(
            i is not None and i.publisher_count >= 1 and i.subscriber_count >= 1
            for i in infos.values()
        )
        if complete or time.monotonic() > t_end:
            break
        time.sleep(0.5)
    out["topics"] = {t: list(v) for t, v in topics.items()}
    out["info"] = {
        t: None
        if i is None
        else {
            side: [
                {"node": e.node_name, "namespace": e.node_namespace, "type": e.topic_type}
                | {"type_hash": e.type_hash, "qos": e.qos}
                for e in getattr(i, side)
            ]
            for side in ("publishers", "subscribers")
        }
        for t, i in infos.items()
    }

    # 2. state
    errors: list[str] = []

    class Errors(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            errors.append(record.getMessage())

    logging.getLogger("zenoh_ros2_sdk").addHandler(Errors(logging.ERROR))
    rec = {t: Recorder() for t in ("/dsteleop/palm_pose", "/dsteleop/finger_state")}
    rec["/dsteleop/joint_states"] = Recorder()
    subs = [
        ROS2Subscriber(topic=t, msg_type=ours[t], callback=r, domain_id=0, **where)
        for t, r in rec.items()
    ]
    out["keys"] = {s.topic: s.keyexpr for s in subs}
    raw: list[tuple[bytes, bytes]] = []
    session = subs[0].session_mgr.session
    raw_sub = session.declare_subscriber(
        subs[0].keyexpr,
        lambda s: raw.append((bytes(s.payload.to_bytes()), bytes(s.attachment.to_bytes()))),
    )
    t_end = time.monotonic() + 10.0  # the subscriptions reach the far end
    while not all(r.newest() is not None for r in rec.values()) and time.monotonic() < t_end:
        time.sleep(0.05)
    n0 = len(raw)
    time.sleep(args.listen_s)
    window = raw[n0:]
    decode = generate_dynamic(POSE, schema(POSE))[POSE]
    store = subs[0].session_mgr.store
    both = [(pose_of(store.deserialize_cdr(b, POSE)), pose_of(decode(b))) for b, _ in window]
    # rmw_zenoh's attachment: sequence number, source stamp [ns], GID length, GID
    seqs = [struct.unpack_from("<q", a)[0] for _, a in window]
    stamps = [p["stamp_ns"] for p, _ in both]
    span_s = (stamps[-1] - stamps[0]) * 1e-9 if len(stamps) > 1 else 0.0
    newest = rec["/dsteleop/palm_pose"].newest()
    out["state"] = {
        "n": len(window),
        # the far end's rate, as its stamps say (the client's own clock sees bursts when the
        # machine is busy), and how many its sequence numbers say were lost
        "rate_hz": (len(window) - 1) / span_s if span_s > 0 else 0.0,
        "lost": (seqs[-1] - seqs[0] + 1 - len(seqs)) if seqs else None,
        "attachment_bytes": sorted({len(a) for _, a in window}),
        "newest": None if newest is None else pose_of(newest),
        "fingers": None,
        "joints": None,
        "decoded_twice": len(both),
        "cdr_agree": all(a == b for a, b in both),
        "sdk_errors": errors,
    }
    f = rec["/dsteleop/finger_state"].newest()
    j = rec["/dsteleop/joint_states"].newest()
    if f is not None:
        out["state"]["fingers"] = dict(zip(f.name, map(float, f.position), strict=True))
    if j is not None:
        out["state"]["joints"] = dict(zip(j.name, map(float, j.position), strict=True))
    raw_sub.undeclare()

    # 3. commands
    import numpy as np

    start = out["state"]["newest"]
    result: dict[str, Any] = {"sent": 0}
    if start is not None and f is not None:
        pose_pub = ROS2Publisher(
            topic="/dsteleop/palm_pose_command", msg_type=POSE, domain_id=0, **where
        )
        finger_pub = ROS2Publisher(
            topic="/dsteleop/finger_command", msg_type=JOINTS, domain_id=0, **where
        )
        T = store.types
        target = [start["p_m"][0], start["p_m"][1] + args.offset_m, start["p_m"][2]]
        qx, qy, qz, qw = start["q_xyzw"]
        names = list(f.name)
        encode_pose = serialize_dynamic(POSE, schema(POSE))[POSE]
        encode_joints = serialize_dynamic(JOINTS, schema(JOINTS))[JOINTS]
        same_bytes = True
        time.sleep(0.5)  # the far end's subscriptions match the new publishers
        t_end = time.monotonic() + args.command_s
        while time.monotonic() < t_end:
            ns = time.time_ns()
            stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            header = T["std_msgs/msg/Header"](stamp=stamp, frame_id=start["frame_id"])
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=target[0], y=target[1], z=target[2]),
                orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            )
            pose_pub.publish(header=header, pose=pose)
            openness = np.full(len(names), args.openness)
            empty = np.zeros(0)
            finger_pub.publish(
                header=header, name=names, position=openness, velocity=empty, effort=empty
            )
            if result["sent"] % 10 == 0:
                msg = T[POSE](header=header, pose=pose)
                plain = {
                    "header": {
                        "stamp": {"sec": stamp.sec, "nanosec": stamp.nanosec},
                        "frame_id": start["frame_id"],
                    },
                    "pose": {
                        "position": dict(zip("xyz", target, strict=True)),
                        "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
                    },
                }
                same_bytes &= bytes(store.serialize_cdr(msg, POSE)) == bytes(encode_pose(plain))
                jmsg = T[JOINTS](
                    header=header, name=names, position=openness, velocity=empty, effort=empty
                )
                jplain = {
                    "header": plain["header"],
                    "name": names,
                    "position": [float(x) for x in openness],
                    "velocity": [],
                    "effort": [],
                }
                same_bytes &= bytes(store.serialize_cdr(jmsg, JOINTS)) == bytes(
                    encode_joints(jplain)
                )
            result["sent"] += 1
            time.sleep(1 / 30)
        time.sleep(0.5)
        result["target_m"] = target
        result["reached"] = pose_of(rec["/dsteleop/palm_pose"].newest())
        fin = rec["/dsteleop/finger_state"].newest()
        result["fingers"] = dict(zip(fin.name, map(float, fin.position), strict=True))
        result["same_bytes_as_second_cdr"] = same_bytes
        result["keys"] = {p.topic: p.keyexpr for p in (pose_pub, finger_pub)}
        pose_pub.close()
        finger_pub.close()
    out["command"] = result
    for s in subs:
        s.close()
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
