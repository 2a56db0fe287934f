"""The robot link's wire format at the byte level (app/link/ros.py, docs/link.md), its
configuration file and the robot limits' clamp. No session here: tests/test_link_live.py runs
real Zenoh sessions and processes."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest

from dsteleop.app.link import ros
from dsteleop.app.link.config import (
    LinkConfig,
    link_config_from_json,
    link_limits,
    read_link_config,
)
from dsteleop.app.ports import RobotLimits
from dsteleop.arbitration import HandState
from dsteleop.arbitration.se3 import so3_exp
from dsteleop.errors import ConfigError, InputError

# Type hashes published outside rosbags: std_msgs/String is rmw_zenoh's design document's own
# example key, sensor_msgs/JointState a ROS 2 interface package's test, PoseStamped's prefix a
# key expression recorded from a running rmw_zenoh system (docs/link.md, "Verified").
STRING_KEY = (
    "0/chatter/std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
)
JOINT_STATE_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
POSE_STAMPED_HASH_PREFIX = "RIHS01_10f3786d7d40fd2b"


def _cdr_string(s: str, offset: int) -> tuple[bytes, int]:
    """A CDR string at body offset `offset`: 4-aligned uint32 length (with NUL), bytes, NUL."""
    pad = b"\x00" * (-offset % 4)
    raw = s.encode() + b"\x00"
    out = pad + struct.pack("<I", len(raw)) + raw
    return out, offset + len(out)


def test_key_expressions_are_rmw_zenohs():
    assert ros.key_expr(0, "/chatter", "std_msgs/msg/String") == STRING_KEY
    assert ros.key_expr(0, "chatter", "std_msgs/msg/String") == STRING_KEY
    assert ros.type_hash(ros.JOINT_STATE) == JOINT_STATE_HASH
    assert ros.type_hash(ros.POSE_STAMPED).startswith(POSE_STAMPED_HASH_PREFIX)
    assert len(ros.type_hash(ros.POSE_STAMPED)) == len("RIHS01_") + 64
    assert ros.key_expr(3, "/robot1/cmd", ros.POSE_STAMPED) == (
        "3/robot1/cmd/geometry_msgs::msg::dds_::PoseStamped_/" + ros.type_hash(ros.POSE_STAMPED)
    )
    assert ros.topic_wildcard(0, "/robot1/cmd") == "0/robot1/cmd/*/*"
    assert ros.type_of_key(STRING_KEY) == ("std_msgs::msg::dds_::String_", STRING_KEY[-71:])


def test_pose_stamped_bytes_are_the_cdr_of_the_ros2_definition():
    # Built by hand from the CDR rules and geometry_msgs/PoseStamped's definition:
    # Header{Time{int32 sec, uint32 nanosec}, string frame_id}, Pose{Point{3 float64},
    # Quaternion{x, y, z, w float64}}; doubles 8-aligned from the start of the body.
    p = np.array([0.5, -0.25, 0.75])
    R = so3_exp(np.array([0.0, 0.0, math.pi / 2]))  # 90 degrees about z
    stamp_ns = 1_700_000_000 * 10**9 + 123_456_789
    body = struct.pack("<iI", 1_700_000_000, 123_456_789)
    s, off = _cdr_string("base", len(body))
    body += s
    body += b"\x00" * (-off % 8)
    h = math.sqrt(0.5)
    body += struct.pack("<7d", 0.5, -0.25, 0.75, 0.0, 0.0, h, h)
    expected = b"\x00\x01\x00\x00" + body
    got = ros.encode_pose(p, R, "base", stamp_ns)
    assert got[:4] == expected[:4]
    # the quaternion comes from a matrix: equal to the last bits, not necessarily bit for bit
    assert got[:-56] == expected[:-56]
    np.testing.assert_allclose(
        struct.unpack("<7d", got[-56:]), struct.unpack("<7d", expected[-56:]), atol=1e-15
    )
    # rosbags reads the hand-built bytes as the same message
    msg = ros.decode_pose(expected)
    np.testing.assert_allclose(msg.p_m, p)
    np.testing.assert_allclose(msg.R, R, atol=1e-12)
    assert (msg.frame_id, msg.stamp_ns) == ("base", stamp_ns)


def test_joint_state_bytes_are_the_cdr_of_the_ros2_definition():
    # Header, string[] name, float64[] position, velocity, effort (uint32 counts).
    body = struct.pack("<iI", 7, 8)
    s, off = _cdr_string("", len(body))
    body += s
    body += b"\x00" * (-off % 4) + struct.pack("<I", 2)
    off = len(body)
    for n in ("thumb", "index"):
        s, off = _cdr_string(n, off)
        body += s
    body += b"\x00" * (-off % 4) + struct.pack("<I", 2)
    body += b"\x00" * (-len(body) % 8) + struct.pack("<2d", 0.25, 1.0)
    body += struct.pack("<II", 0, 0)
    expected = b"\x00\x01\x00\x00" + body
    assert ros.encode_joints(("thumb", "index"), np.array([0.25, 1.0]), 7 * 10**9 + 8) == expected
    msg = ros.decode_joints(expected)
    assert msg.names == ("thumb", "index")
    np.testing.assert_array_equal(msg.positions, [0.25, 1.0])
    assert msg.stamp_ns == 7 * 10**9 + 8


def test_round_trips():
    rng = np.random.default_rng(3)
    for _ in range(20):
        p = rng.normal(size=3)
        R = so3_exp(rng.normal(size=3))
        m = ros.decode_pose(ros.encode_pose(p, R, "world", 42))
        np.testing.assert_allclose(m.p_m, p, rtol=0, atol=0)
        np.testing.assert_allclose(m.R, R, atol=1e-12)
        q = rng.uniform(-3, 3, size=9)
        names = tuple(f"j{i}" for i in range(9))
        j = ros.decode_joints(ros.encode_joints(names, q, 43))
        assert j.names == names
        np.testing.assert_array_equal(j.positions, q)


def test_attachment_is_zenohs_serialisation_of_rmw_zenohs_fields():
    import zenoh.ext as ze

    gid = bytes(range(16))
    a = ros.Attachment(seq=123456, stamp_ns=1_700_000_000_123_456_789, gid=gid)
    raw = ros.encode_attachment(a)
    # rmw_zenoh serialises (int64 seq, int64 stamp, uint8[16] gid) with zenoh-ext's serializer
    assert raw == ze.z_serialize((ze.Int64(a.seq), ze.Int64(a.stamp_ns), gid)).to_bytes()
    assert len(raw) == 33 and raw[16] == 16 and raw[17:] == gid
    assert raw[:8] == (123456).to_bytes(8, "little")
    assert ros.decode_attachment(raw) == a
    assert len(ros.gid("zid", "/topic")) == 16


@pytest.mark.parametrize(
    ("data", "match"),
    [(None, "without its attachment"), (b"\x01" * 20, "malformed"), (b"\x00" * 33, "malformed")],
)
def test_bad_attachment_is_one_clear_error(data, match):
    with pytest.raises(InputError, match=match):
        ros.decode_attachment(data)


def test_wrong_type_is_one_clear_error():
    pose = ros.encode_pose(np.zeros(3), np.eye(3), "base", 1)
    joints = ros.encode_joints(("a", "b"), np.array([0.1, 0.2]), 1)
    with pytest.raises(InputError, match=r"not a CDR sensor_msgs/msg/JointState"):
        ros.decode_joints(pose)
    with pytest.raises(InputError, match=r"not a CDR geometry_msgs/msg/PoseStamped"):
        ros.decode_pose(joints)
    with pytest.raises(InputError, match="encapsulation header"):
        ros.decode_pose(b"\x07\x07\x00\x00" + pose[4:])
    with pytest.raises(InputError, match="not a CDR"):
        ros.decode_pose(b"")
    bad = bytearray(pose)
    bad[-8:] = struct.pack("<d", 0.0)  # w = 0 with x = y = z = 0: not a rotation
    with pytest.raises(InputError, match="invalid pose"):
        ros.decode_pose(bytes(bad))
    with pytest.raises(InputError, match="names no ROS 2 type"):
        ros.type_of_key("chatter")


def test_every_cut_cdr_buffer_is_one_clear_error():
    """A buffer cut anywhere is an InputError (what a subscription drops as `bad_payload`),
    never another exception that would end the end that received it."""
    pose = ros.encode_pose(np.array([0.5, 0.1, 0.4]), np.eye(3), "base", 123)
    joints = ros.encode_joints(("thumb", "index"), np.array([0.3, 0.7]), 123)
    for data, decode in ((pose, ros.decode_pose), (joints, ros.decode_joints)):
        for n in range(len(data)):
            with pytest.raises(InputError):
                decode(data[:n])


def test_an_end_that_only_connects_is_a_zenoh_client():
    """Peers that listen nowhere get nothing through a router (docs/link.md, "Behind a Zenoh
    router"): such an end is a client; one that listens is a peer."""
    from dsteleop.app.link.config import Endpoints
    from dsteleop.app.link.session import session_mode

    ep = "tcp/127.0.0.1:7447"
    assert session_mode(Endpoints(connect=(ep,))) == "client"
    assert session_mode(Endpoints(listen=(ep,))) == "peer"
    assert session_mode(Endpoints(listen=("tcp/127.0.0.1:0",), connect=(ep,))) == "peer"
    c = LinkConfig()
    assert (session_mode(c.near), session_mode(c.far)) == ("client", "peer")


def test_config_defaults_file_and_errors(tmp_path):
    c = LinkConfig()
    assert c.far.listen == ("tcp/127.0.0.1:7447",) and c.near.connect == ("tcp/127.0.0.1:7447",)
    # the robot's fingers and limits come from its description (twice its speed limits)
    resolved, desc = c.for_robot()
    assert desc.name == "iiwa" and resolved.finger_names == ("thumb", "index", "middle", "ring")
    assert resolved.limits == link_limits(desc)
    assert resolved.limits.max_speed_m_s == 2 * desc.max_speed_m_s
    panda, _ = LinkConfig(robot="panda").for_robot()
    assert panda.finger_names == ("gripper",)
    with pytest.raises(ConfigError, match="are not robot iiwa's"):
        LinkConfig(finger_names=("gripper",)).for_robot()
    f = tmp_path / "link.json"
    f.write_text("{}")
    assert read_link_config(f) == c
    f.write_text(json.dumps(c.to_json()))
    assert read_link_config(f) == c
    f.write_text(json.dumps(resolved.to_json()))
    assert read_link_config(f) == resolved
    # a description file is read from the configuration's folder; a missing one is named
    # as the file's field (not --robot's)
    f.write_text(json.dumps({"robot": "my_arm.toml"}))
    with pytest.raises(InputError, match=f"link config {f}: field robot: no such robot"):
        read_link_config(f)
    (tmp_path / "my_arm.toml").write_text("")
    assert read_link_config(f).robot == str(tmp_path / "my_arm.toml")
    d = link_config_from_json(
        {"domain_id": 5, "topics": {"command_pose": "/arm/target"}, "finger_names": ["gripper"]}
    )
    assert d.domain_id == 5 and d.topics.command_pose == "/arm/target"
    assert d.finger_names == ("gripper",)
    for bad, match in [
        ({"nope": 1}, "unknown field link.nope"),
        ({"topics": {"x": "/a"}}, "unknown field topics.x"),
        ({"near": {"connect": ["127.0.0.1:7447"]}}, "not a Zenoh endpoint"),
        ({"near": {"listen": [], "connect": []}}, "needs a listen or a connect"),
        ({"topics": {"command_pose": "bad topic"}}, "not a ROS 2 topic name"),
        ({"topics": {"state_pose": "/dsteleop/palm_pose_command"}}, "same name"),
        ({"domain_id": 999}, "domain_id"),
        ({"command_timeout_s": 0}, "command_timeout_s must be > 0"),
        ({"limits": {"max_speed_m_s": 1.0}}, "limits"),
        ([], "JSON object"),
    ]:
        with pytest.raises(ConfigError, match=match):
            link_config_from_json(bad)
    f.write_text("{not json")
    with pytest.raises(InputError, match="not a JSON file"):
        read_link_config(f)
    with pytest.raises(InputError, match="file not found"):
        read_link_config(tmp_path / "missing.json")


def _X(
    p: tuple[float, ...],
    rotvec: tuple[float, ...] = (0.0, 0.0, 0.0),
    g: tuple[float, ...] = (1.0, 1.0),
) -> HandState:
    return HandState.from_rotvec(np.array(p, float), np.array(rotvec, float), np.array(g, float))


def test_limits_clamp_keeps_commands_inside_the_box_and_speeds():
    lim = RobotLimits((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0.5, 1.0, 2.0)
    X0 = _X((0.5, 0.5, 0.5))
    dt = 0.1
    # far outside the box: clipped into it, and a step of at most 0.5 m/s * 0.1 s
    X = lim.clamp(X0, _X((9.0, 0.5, 0.5)), dt)
    assert np.all(X.position <= 1.0) and np.all(X.position >= 0.0)
    assert np.linalg.norm(X.position - X0.position) == pytest.approx(0.05, rel=1e-9)
    # a small step inside the limits passes unchanged
    X = lim.clamp(X0, _X((0.52, 0.5, 0.49), (0.05, 0, 0), (0.9, 1.0)), dt)
    np.testing.assert_allclose(X.position, (0.52, 0.5, 0.49), atol=1e-12)
    np.testing.assert_allclose(X.rotvec(), (0.05, 0, 0), atol=1e-12)
    np.testing.assert_allclose(X.openness, (0.9, 1.0), atol=1e-12)
    # rotation and fingers limited: 1 rad/s and 2 /s over 0.1 s
    X = lim.clamp(X0, _X((0.5, 0.5, 0.5), (0.0, 0.0, 1.5), (0.0, 1.0)), dt)
    assert np.linalg.norm(X.rotvec()) == pytest.approx(0.1, rel=1e-9)
    np.testing.assert_allclose(X.openness, (0.8, 1.0), atol=1e-12)
    # openness never leaves [0, 1]
    X = lim.clamp(_X((0.5, 0.5, 0.5), g=(0.05, 1.0)), _X((0.5, 0.5, 0.5), g=(-3.0, 7.0)), dt)
    np.testing.assert_allclose(X.openness, (0.0, 1.0), atol=1e-12)
    with pytest.raises(ConfigError, match="below max"):
        RobotLimits((0.0, 0.0, 1.0), (1.0, 1.0, 1.0), 0.5, 1.0, 2.0)
    with pytest.raises(ConfigError, match="max_speed_m_s"):
        RobotLimits((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0.0, 1.0, 2.0)


# rmw_zenoh's design document (docs/design.md, "Graph Cache", ros2/rmw_zenoh at 99a6a2bd):
# the liveliness tokens of demo_nodes_cpp's listener node and talker's publisher, verbatim.
LISTENER_NODE_TOKEN = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
TALKER_PUB_TOKEN = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
)
LISTENER_SUB_TOKEN = (
    "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    "std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,"
)


def test_liveliness_keys_are_rmw_zenohs_design_examples():
    zl, zt = "aac3178e146ba6f1fc6e6a4085e77f21", "8b20917502ee955ac4476e0266340d5c"
    listener, talker = ros.RosNode("listener"), ros.RosNode("talker")
    assert ros.liveliness_key(2, zl, listener, 0, 0, ros.NODE) == LISTENER_NODE_TOKEN
    got = ros.liveliness_key(
        2, zt, talker, 0, 10, ros.PUBLISHER, "/chatter", "std_msgs/msg/String", ros.QoS(depth=7)
    )
    assert got == TALKER_PUB_TOKEN
    # field by field, in the order of liveliness_utils.cpp's KeyexprIndex
    fields = got.split("/")
    assert fields == TALKER_PUB_TOKEN.split("/")
    assert len(fields) == 13
    admin, dom, zid, nid, eid, kind, enclave, ns, name, topic, typ, hsh, qos = fields
    assert (admin, dom, zid, nid, eid, kind) == ("@ros2_lv", "2", zt, "0", "10", "MP")
    assert (enclave, ns, name, topic) == ("%", "%", "talker", "%chatter")
    assert (typ, hsh, qos) == ("std_msgs::msg::dds_::String_", STRING_KEY[-71:], "::,7:,:,:,,")
    # a topic without its leading "/" is the same fully qualified name
    assert (
        ros.liveliness_key(
            2,
            zl,
            listener,
            0,
            10,
            ros.SUBSCRIPTION,
            "chatter",
            "std_msgs/msg/String",
            ros.QoS(depth=10),
        )
        == LISTENER_SUB_TOKEN
    )


def test_liveliness_key_of_a_link_topic_and_its_qos():
    node = ros.RosNode("dsteleop", namespace="/lab/arm1")
    key = ros.liveliness_key(
        0, "0123abcd", node, 0, 1, ros.PUBLISHER, "/dsteleop/palm_pose_command", ros.POSE_STAMPED
    )
    assert key == (
        "@ros2_lv/0/0123abcd/0/1/MP/%/%lab%arm1/dsteleop/%dsteleop%palm_pose_command/"
        "geometry_msgs::msg::dds_::PoseStamped_/"
        + ros.type_hash(ros.POSE_STAMPED)
        + "/2::,1:,:,:,,"
    )
    # rmw_zenoh's compact QoS: reliability, durability, history,depth, deadline s,ns,
    # lifespan s,ns, liveliness,lease s,ns; empty where the value is rmw_zenoh's default
    # (reliable=1, volatile=2, keep_last=1, depth 42, durations infinite, automatic=1)
    assert ros.qos_key(ros.QoS()) == "::,:,:,:,,"
    assert ros.qos_key(ros.LINK_QOS) == "2::,1:,:,:,,"
    assert (
        ros.qos_key(
            ros.QoS(
                reliability=ros.RELIABLE,
                durability=ros.TRANSIENT_LOCAL,
                history=ros.KEEP_ALL,
                depth=5,
                deadline=(1, 500),
                lifespan=(2, 0),
                liveliness=3,
                lease=(0, 250_000_000),
            )
        )
        == ":1:2,5:1,500:2,0:3,0,250000000"
    )
    assert ros.mangle("/a/b_c/") == "%a%b_c%"
    with pytest.raises(ValueError):
        ros.liveliness_key(0, "z", node, 0, 1, ros.PUBLISHER)  # a publisher needs its topic
    with pytest.raises(ValueError):
        ros.liveliness_key(0, "z", node, 0, 0, ros.NODE, "/t", ros.POSE_STAMPED)
    with pytest.raises(ValueError):
        ros.liveliness_key(0, "z", node, 0, 0, "XX")
