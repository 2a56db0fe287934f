"""Assemble a robot from its description (`robot.description`): one URDF text for `loadURDF`.

The arm's URDF is read from the installed `pybullet_data` or the repository at run time
(never fetched), its mesh paths are made absolute (`package://` prefixes resolved beside the
URDF). A mounted hand's links and joints are added with the fixed joint that joins them (the
iiwa: the hand of `assets/dsteleop_hand.urdf`, its palm's inner face `FLANGE_TO_PALM_M` above
the link-7 frame: the flange face sits 0.045 m above that frame, the palm plate is 0.030 m
thick). A palm frame offset from its link gets a massless link `dsteleop_palm` on a fixed
joint. The combined text is written to a temporary file for `loadURDF`.
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from dsteleop.errors import InputError
from dsteleop.robot.bullet import pb
from dsteleop.robot.description import RobotDescription, load_description

#: The iiwa's arm joints and hand mount (its description, `robots/iiwa.toml`, is the source).
ARM_JOINTS: tuple[str, ...] = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
FLANGE_TO_PALM_M = 0.075
PALM_FRAME_JOINT = "dsteleop_palm_joint"


def _read_urdf(desc: RobotDescription, ref: str) -> ET.Element:
    path = desc.resolve(ref)
    if not path.is_file():
        raise InputError(f"robot {desc.name}: no URDF {path} (is it installed fully?)")
    root = ET.parse(path).getroot()
    for mesh in root.iter("mesh"):
        fn = mesh.get("filename", "").removeprefix("package://")
        mesh.set("filename", str((path.parent / fn).resolve()))
    return root


def _xyz_rpy(xyz: tuple[float, ...], rpy: tuple[float, ...]) -> dict[str, str]:
    return {"xyz": " ".join(f"{v:.9g}" for v in xyz), "rpy": " ".join(f"{v:.9g}" for v in rpy)}


def robot_urdf_text(desc: RobotDescription | None = None) -> str:
    """The robot's URDF as one text (module docstring); default the iiwa."""
    desc = desc or load_description("iiwa")
    arm = _read_urdf(desc, desc.urdf)
    if desc.mount is not None:
        m = desc.mount
        for child in list(_read_urdf(desc, m.urdf)):
            arm.append(child)
        joint = ET.SubElement(arm, "joint", {"name": m.joint, "type": "fixed"})
        ET.SubElement(joint, "parent", {"link": m.parent_link})
        ET.SubElement(joint, "child", {"link": m.child_link})
        ET.SubElement(joint, "origin", _xyz_rpy(m.xyz_m, m.rpy_rad))
    if desc.palm_frame_link != desc.palm_link:
        link = ET.SubElement(arm, "link", {"name": desc.palm_frame_link})
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "mass", {"value": "0.001"})
        ET.SubElement(
            inertial,
            "inertia",
            {"ixx": "1e-7", "ixy": "0", "ixz": "0", "iyy": "1e-7", "iyz": "0", "izz": "1e-7"},
        )
        joint = ET.SubElement(arm, "joint", {"name": PALM_FRAME_JOINT, "type": "fixed"})
        ET.SubElement(joint, "parent", {"link": desc.palm_link})
        ET.SubElement(joint, "child", {"link": desc.palm_frame_link})
        ET.SubElement(joint, "origin", _xyz_rpy(desc.palm_xyz_m, desc.palm_rpy_rad))
    if desc.name == "iiwa":
        arm.set("name", "iiwa_dsteleop_hand")  # the name sessions and scenes always had
    return ET.tostring(arm, encoding="unicode")


def palm_tip_joints(desc: RobotDescription, urdf_text: str) -> tuple[str, ...]:
    """The fixed joints from the last arm joint's link to the palm frame, in order.

    Raises:
        InputError: the palm frame is not reached from the wrist through fixed joints.
    """
    root = ET.fromstring(urdf_text)
    joints = {j.get("name"): j for j in root.iter("joint")}
    wrist = joints[desc.arm_joints[-1]]
    child = wrist.find("child")
    link = child.get("link") if child is not None else None
    fixed: dict[str | None, list[ET.Element]] = {}
    for j in root.iter("joint"):
        p = j.find("parent")
        if j.get("type") == "fixed" and p is not None:
            fixed.setdefault(p.get("link"), []).append(j)
    path: list[str] = []
    frontier = [(link, path)]
    while frontier:
        at, via = frontier.pop()
        if at == desc.palm_frame_link:
            return tuple(via)
        for j in fixed.get(at, []):
            c = j.find("child")
            frontier.append((c.get("link") if c is not None else None, [*via, str(j.get("name"))]))
    raise InputError(
        f"robot description {desc.path}: palm.link {desc.palm_link!r} is not fixed to the "
        f"arm's last joint {desc.arm_joints[-1]!r}"
    )


@dataclass(frozen=True)
class JointInfo:
    """One movable joint of a body, addressed by name.

    Attributes:
        name: URDF joint name.
        index: PyBullet joint index (also the index of its child link).
        lower_rad: lower limit [rad] (a prismatic joint's: [m]).
        upper_rad: upper limit [rad] (or [m]).
        max_force: motor effort limit [N m] (or [N]).
        max_velocity_radps: velocity limit [rad/s] (or [m/s]).
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
    """Load the robot into `client` with a fixed base and return its joint/link tables
    (the movable joints: revolute and prismatic).

    Args:
        client: PyBullet client id.
        base_position_m: where the arm's base stands [m].
        urdf_text: the combined URDF (default: `robot_urdf_text()`, the iiwa).
    """
    text = urdf_text if urdf_text is not None else robot_urdf_text()
    with tempfile.TemporaryDirectory(prefix="dsteleop_robot_") as tmp:
        path = Path(tmp) / "robot.urdf"
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
        if info[2] in (pb.JOINT_REVOLUTE, pb.JOINT_PRISMATIC):
            name = info[1].decode()
            joints[name] = JointInfo(
                name, j, float(info[8]), float(info[9]), float(info[10]), float(info[11])
            )
    return LoadedRobot(body, joints, links)
