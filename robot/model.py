"""Assemble the robot: the KUKA iiwa arm of `pybullet_data` with the project's hand at its flange.

The arm's URDF is read from the installed `pybullet_data` at run time (never fetched), its mesh
paths are made absolute, the hand's links and joints (`assets/dsteleop_hand.urdf`) are added,
and a fixed joint `flange_to_palm` puts the palm's inner face `FLANGE_TO_PALM_M` above the
iiwa's link-7 frame along its z axis (the flange face sits 0.045 m above that frame, the palm
plate is 0.030 m thick). The combined text is written to a temporary file for `loadURDF`.
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import pybullet_data

from dsteleop.errors import InputError
from dsteleop.robot.bullet import pb
from dsteleop.robot.hand_urdf import ASSET_PATH, MOUNT_PARENT_LINK, PALM_LINK

ARM_URDF = "kuka_iiwa/model.urdf"
ARM_JOINTS: tuple[str, ...] = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
FLANGE_TO_PALM_M = 0.075


def robot_urdf_text() -> str:
    """The combined arm + hand URDF, with absolute mesh paths into `pybullet_data`."""
    data = Path(pybullet_data.getDataPath())
    arm_path = data / ARM_URDF
    if not arm_path.is_file():
        raise InputError(f"pybullet_data has no {ARM_URDF} (is pybullet installed fully?)")
    arm = ET.parse(arm_path).getroot()
    for mesh in arm.iter("mesh"):
        fn = mesh.get("filename", "")
        mesh.set("filename", str((arm_path.parent / fn).resolve()))
    hand = ET.parse(ASSET_PATH).getroot()
    for child in list(hand):
        arm.append(child)
    mount = ET.SubElement(arm, "joint", {"name": "flange_to_palm", "type": "fixed"})
    ET.SubElement(mount, "parent", {"link": MOUNT_PARENT_LINK})
    ET.SubElement(mount, "child", {"link": PALM_LINK})
    ET.SubElement(mount, "origin", {"xyz": f"0 0 {FLANGE_TO_PALM_M}", "rpy": "0 0 0"})
    arm.set("name", "iiwa_dsteleop_hand")
    return ET.tostring(arm, encoding="unicode")


@dataclass(frozen=True)
class JointInfo:
    """One movable joint of a body, addressed by name.

    Attributes:
        name: URDF joint name.
        index: PyBullet joint index (also the index of its child link).
        lower_rad: lower limit [rad].
        upper_rad: upper limit [rad].
        max_force: motor effort limit [N m].
        max_velocity_radps: velocity limit [rad/s].
    """

    name: str
    index: int
    lower_rad: float
    upper_rad: float
    max_force: float
    max_velocity_radps: float


@dataclass(frozen=True)
class LoadedRobot:
    """A robot body in a PyBullet client with its joints and links by name."""

    body: int
    joints: dict[str, JointInfo]
    links: dict[str, int]  # link name -> link index (-1 for the base)


def load_robot(
    client: int,
    base_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    urdf_text: str | None = None,
) -> LoadedRobot:
    """Load the arm + hand into `client` with a fixed base and return its joint/link tables.

    Args:
        client: PyBullet client id.
        base_position_m: where the arm's base stands [m].
        urdf_text: the combined URDF (default: `robot_urdf_text()`).
    """
    text = urdf_text if urdf_text is not None else robot_urdf_text()
    with tempfile.TemporaryDirectory(prefix="dsteleop_robot_") as tmp:
        path = Path(tmp) / "iiwa_dsteleop_hand.urdf"
        path.write_text(text)
        flags = pb.URDF_USE_INERTIA_FROM_FILE
        body = pb.loadURDF(
            str(path), base_position_m, useFixedBase=True, flags=flags, physicsClientId=client
        )
    joints: dict[str, JointInfo] = {}
    links: dict[str, int] = {}
    base_name = pb.getBodyInfo(body, physicsClientId=client)[0].decode()
    links[base_name] = -1
    for j in range(pb.getNumJoints(body, physicsClientId=client)):
        info = pb.getJointInfo(body, j, physicsClientId=client)
        links[info[12].decode()] = j
        if info[2] == pb.JOINT_REVOLUTE:
            name = info[1].decode()
            joints[name] = JointInfo(
                name, j, float(info[8]), float(info[9]), float(info[10]), float(info[11])
            )
    return LoadedRobot(body, joints, links)
