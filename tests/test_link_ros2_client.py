"""The robot link against an outside ROS 2-over-Zenoh client installed from PyPI in a virtual
environment of its own (tests/outside_env.py): zenoh-ros2-sdk, which computes its own RIHS01
type hashes from the .msg definitions, builds its own rmw_zenoh key expressions, liveliness
tokens and attachments, and opens its session with rmw_zenoh's default configuration; every
payload it reads or writes is also read or written by a second CDR implementation,
mcap-ros2-support's (tests/outside_ros2_client.py, which imports nothing of dsteleop).

Both ends of the link run as in use: `dsteleop robot-sim` in a child process, the near end
(`ZenohRobot`) in this one; behind a Zenoh router (a child process, as `zenohd`) with
docs/link.md's endpoints for a ROS 2 system, and peer to peer with the link's defaults, the
client connecting where a ROS 2 node would (the router; the robot's endpoint)."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dsteleop.app.link import ros
from dsteleop.app.link.config import LinkConfig, read_link_config
from dsteleop.app.link.far import FAR_NODE
from dsteleop.app.link.near import NEAR_NODE, ZenohRobot
from dsteleop.arbitration.se3 import matrix_from_quat_wxyz
from tests.link_rig import Far, Router, free_port
from tests.outside_env import ROS2_CLIENT, InstallError, python_with

pytestmark = pytest.mark.slow

CLIENT = Path(__file__).with_name("outside_ros2_client.py")
RATE_HZ = 30.0
LISTEN_S = 3.0
COMMAND_S = 3.0
OFFSET_M = 0.05
OPENNESS = 0.3


@pytest.fixture(scope="module")
def client_python() -> Path:
    try:
        return python_with(ROS2_CLIENT)
    except InstallError as exc:
        pytest.skip(
            f"the outside ROS 2 client cannot be installed ({' '.join(ROS2_CLIENT)}): {exc}"
        )


def run_client(py: Path, where: str, tmp_path: Path) -> dict[str, Any]:
    """The outside client against the link at `where` (host:port); its JSON report."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["ZENOH_ROS2_SDK_CACHE"] = str(tmp_path / "sdk-cache")  # stays empty: nothing downloaded
    r = subprocess.run(
        [str(py), str(CLIENT), "--router", where, "--msgs", str(tmp_path / "msgs"),
         "--listen-s", str(LISTEN_S), "--command-s", str(COMMAND_S),
         "--offset-m", str(OFFSET_M), "--openness", str(OPENNESS)],
        capture_output=True, text=True, timeout=180, cwd=tmp_path, env=env,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    report: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    return report


@pytest.mark.parametrize("setup", ["router", "peer to peer"])
def test_an_outside_ros2_client_discovers_reads_and_drives_the_link(
    tmp_path: Path, client_python: Path, setup: str
) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    router = Router(port) if setup == "router" else None
    if router is not None:  # docs/link.md's endpoints for a ROS 2 system on rmw_zenoh
        ends = {"far": {"listen": [], "connect": [ep]}, "near": {"listen": [], "connect": [ep]}}
    else:  # the link's defaults: the robot listens, dsteleop connects
        ends = {"far": {"listen": [ep]}, "near": {"connect": [ep]}}
    cfg = tmp_path / "link.json"
    cfg.write_text(json.dumps({**ends, "connect_timeout_s": 10.0}))
    far = robot = None
    try:
        far = Far(cfg)
        robot = ZenohRobot(read_link_config(cfg))
        t0 = time.monotonic()
        home = robot.reset(0.0)  # the near end only listens: the arm stays at home
        fingers, joints = robot.finger_names, robot.joint_names
        report = run_client(client_python, f"127.0.0.1:{port}", tmp_path)
        after = robot.state(time.monotonic() - t0)
        robot.close()
        robot = None
        summary = far.terminate()
    finally:
        if robot is not None:
            robot.close()
        if far is not None and far.proc.poll() is None:
            far.kill()
        if router is not None:
            router.close()
    (tmp_path / "report.json").write_text(json.dumps({"client": report, "far": summary}))
    t = LinkConfig().topics
    types = {
        t.command_pose: ros.POSE_STAMPED,
        t.command_fingers: ros.JOINT_STATE,
        t.state_pose: ros.POSE_STAMPED,
        t.state_joints: ros.JOINT_STATE,
        t.state_fingers: ros.JOINT_STATE,
    }
    near, far_name = NEAR_NODE.name, FAR_NODE.name

    # 1. discovery: every topic of the link with its type, published and subscribed by the
    # right node, with the type hash and the QoS dsteleop declares
    for topic, ros_type in types.items():
        assert report["topics"].get(topic) == [ros_type], report["topics"]
        info = report["info"][topic]
        publisher, subscriber = (near, far_name) if "command" in topic else (far_name, near)
        assert [e["node"] for e in info["publishers"]] == [publisher], info
        assert [e["node"] for e in info["subscribers"]] == [subscriber], info
        for e in info["publishers"] + info["subscribers"]:
            assert e["type"] == ros_type and e["type_hash"] == ros.type_hash(ros_type), e
            assert e["qos"] == "2::,1:,:,:,,", e
    # its own key expressions (from its own type hashes) are ours, character for character
    for topic, key in {**report["keys"], **report["command"]["keys"]}.items():
        assert key == ros.key_expr(0, topic, types[topic]), (topic, key)

    # 2. state: the palm pose at the far end's rate, decoded as the near end decodes it
    state = report["state"]
    assert state["n"] >= 0.5 * RATE_HZ * LISTEN_S and not state["sdk_errors"], state
    assert 0.8 * RATE_HZ <= state["rate_hz"] <= 1.1 * RATE_HZ, state["rate_hz"]
    # the link's publishers drop rather than block: a starved machine loses a few (9 % seen)
    assert state["lost"] <= 0.2 * state["n"] and state["attachment_bytes"] == [33], state
    pose = state["newest"]
    assert pose["frame_id"] == "base"
    assert np.linalg.norm(np.subtract(pose["p_m"], home.X.position)) < 1e-3, (pose, home.X)
    x, y, z, w = pose["q_xyzw"]
    assert np.allclose(matrix_from_quat_wxyz(np.array([w, x, y, z])), home.X.rotation, atol=2e-3)
    assert abs(pose["stamp_ns"] - time.time_ns()) < 60e9  # UNIX time, not the loop's clock
    assert state["decoded_twice"] >= 10 and state["cdr_agree"], state
    assert tuple(state["fingers"]) == tuple(fingers)
    assert np.allclose(list(state["fingers"].values()), home.X.openness, atol=1e-3)
    assert tuple(state["joints"]) == tuple(joints)
    assert np.allclose(list(state["joints"].values()), home.joints, atol=2e-3)

    # 3. commands: its pose and finger commands drove robot-sim, none dropped
    command = report["command"]
    assert command["sent"] >= 0.7 * RATE_HZ * COMMAND_S, command
    assert command["same_bytes_as_second_cdr"], command
    assert summary["applied"] >= 0.5 * command["sent"], summary
    # a command older than 0.2 s on arrival is dropped (the machine may starve a process)
    assert summary["dropped_stale"] <= 0.1 * command["sent"], summary
    assert summary["dropped_out_of_order"] == 0, summary
    assert not any(n for d in summary["dropped_stray"].values() for n in d.values()), summary
    reached = np.array(command["reached"]["p_m"])
    assert np.linalg.norm(reached - command["target_m"]) < 5e-3, command
    assert reached[1] - home.X.position[1] > OFFSET_M - 5e-3
    assert np.allclose(list(command["fingers"].values()), OPENNESS, atol=0.05), command
    # the near end saw the arm where the outside client drove it
    assert after is not None
    assert np.linalg.norm(after.X.position - reached) < 5e-3, (after.X.position, reached)
