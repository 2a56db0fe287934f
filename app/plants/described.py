"""What the Robot port says of a robot description, for every robot built from one
(simulated, recorded, linked): its limits and its joints' order. No PyBullet."""

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
