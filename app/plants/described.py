"""What the Robot port says of a robot description, for every robot built from one
(simulated, recorded, linked): its limits, its joints' order and their units. No PyBullet."""

from __future__ import annotations

from dsteleop.app.ports import RobotLimits
from dsteleop.robot.description import RobotDescription


def limits_of(desc: RobotDescription) -> RobotLimits:
    """The `ports.RobotLimits` a robot description gives."""
    return RobotLimits(
        desc.workspace_min_m,
        desc.workspace_max_m,
        desc.max_speed_m_s,
        desc.max_rate_rad_s,
        desc.max_finger_rate_per_s,
    )


def joint_names_of(desc: RobotDescription) -> tuple[str, ...]:
    """A robot's joints in the order of `RobotState.joints`: arm, then finger joints."""
    return (*desc.arm_joints, *(j.name for j in desc.finger_joints))


#: The unit of a revolute joint's position, and of a prismatic one's.
REVOLUTE_UNIT = "rad"
PRISMATIC_UNIT = "m"


def joint_units_of(desc: RobotDescription) -> tuple[str, ...]:
    """The unit of each joint position, in `joint_names_of` order: "rad" for a revolute
    joint (every arm joint), "m" for a prismatic one (e.g. a parallel gripper's jaws)."""
    return tuple(
        PRISMATIC_UNIT if n in desc.prismatic_joints else REVOLUTE_UNIT
        for n in joint_names_of(desc)
    )
