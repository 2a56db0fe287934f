"""Assemble a robot from its description (`robot.description`): one URDF text for `loadURDF`.

The arm's URDF is read from the installed `pybullet_data`, the repository or the user's
files at run time (never fetched), by the one URDF reader (`robot.urdf`): its mesh paths are
made absolute (`package://` and relative paths resolved against the description's search
path), and a link inertia PyBullet would zero is repaired (logged once per process and
link). A mounted hand's links and joints are added with the fixed joint that joins them (the
iiwa: the hand of `assets/dsteleop_hand.urdf`, its palm's inner face `FLANGE_TO_PALM_M` above
the link-7 frame: the flange face sits 0.045 m above that frame, the palm plate is 0.030 m
thick). A palm frame offset from its link gets a massless link `dsteleop_palm` on a fixed
joint. The combined text is written to a temporary file for `loadURDF`.
"""

from __future__ import annotations

import logging
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from dsteleop.errors import InputError
from dsteleop.robot.bullet import pb
from dsteleop.robot.description import RobotDescription, load_description, urdf_models
from dsteleop.robot.urdf import UrdfModel, repair_inertia

log = logging.getLogger(__name__)

#: The iiwa's arm joints and hand mount (its description, `robots/iiwa.toml`, is the source).
ARM_JOINTS: tuple[str, ...] = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
FLANGE_TO_PALM_M = 0.075
PALM_FRAME_JOINT = "dsteleop_palm_joint"


#: (URDF file, link) pairs whose inertia repair was logged (once per process)
_REPAIRS_LOGGED: set[tuple[str, str]] = set()


def _repair_inertias(model: UrdfModel) -> None:
    """Repair the inertia tensors PyBullet would zero (`robot.urdf.repair_inertia`), and
    say so once per process and link."""
    for link in model.root.findall("link"):
        el = link.find("inertial/inertia")
        if el is None:
            continue
        fixed = repair_inertia(el)
        key = (str(model.path), str(link.get("name")))
        if fixed is not None and key not in _REPAIRS_LOGGED:
            _REPAIRS_LOGGED.add(key)
            before, after = (", ".join(f"{v:.3g}" for v in x) for x in fixed)
            log.warning(
                "%s: link %r: principal moments of inertia (%s) kg m^2 are not physical "
                "(negative, or one above the sum of the other two; PyBullet would zero them): "
                "using (%s)",
                model.path,
                link.get("name"),
                before,
                after,
            )


def _xyz_rpy(xyz: tuple[float, ...], rpy: tuple[float, ...]) -> dict[str, str]:
    return {"xyz": " ".join(f"{v:.9g}" for v in xyz), "rpy": " ".join(f"{v:.9g}" for v in rpy)}


def robot_urdf_text(desc: RobotDescription | None = None) -> str:
    """The robot's URDF as one text (module docstring); default the iiwa."""
    desc = desc or load_description("iiwa")
    models = urdf_models(desc)
    for model in models:
        _repair_inertias(model)
    arm = models[0].root
    if desc.mount is not None:
        m = desc.mount
        for child in list(models[1].root):
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
    joints = UrdfModel.from_text(urdf_text).joints
    link = joints[desc.arm_joints[-1]].child
    fixed: dict[str | None, list[str]] = {}
    for j in joints.values():
        if j.type == "fixed":
            fixed.setdefault(j.parent, []).append(j.name)
    frontier: list[tuple[str | None, list[str]]] = [(link, [])]
    while frontier:
        at, via = frontier.pop()
        if at == desc.palm_frame_link:
            return tuple(via)
        for name in fixed.get(at, []):
            frontier.append((joints[name].child, [*via, name]))
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
