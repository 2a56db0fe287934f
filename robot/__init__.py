"""dsteleop.robot: a simulated arm and hand built from a robot description (robot/robots/*.toml:
the KUKA iiwa with the project's four-finger hand, the Franka Panda with its gripper) and the
kitchen pick-and-place task, in PyBullet.

Public API (see docs/robot.md, docs/robots.md):
    KitchenEnv, EnvConfig                robot + world + task; reset / set_target / step /
                                         state, geometry() and poses() for a viewer
    RobotConfig, BulletArmState, Contact control settings and the per-tick read-back of the
                                         simulated arm (`arm.BulletArm`)
    Workspace                            the box its palm target is clamped into
    PickPlaceTask, TaskConfig, Phase, EventKind, TaskEvent, Outcome
    run_autonomous, goal_seeking_step, noise_free, RunResult   the scripted alpha = 1 run
    SceneGeometry, ScenePoses, VisualGeometry                  viewer export (no pybullet)
    FINGER_NAMES, UTENSIL_NAMES

The loop never sees these classes: it drives a robot through the `Robot` port of
`app/ports.py` (its `RobotState` is the port's measured state), which
`app/plants/simulated.py` implements on a `KitchenEnv`.

Names are resolved lazily, so `import dsteleop.robot.scene` (what a viewer needs) never
loads PyBullet.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dsteleop.robot.arm import BulletArmState, Contact, RobotConfig, Workspace
    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.hand_urdf import FINGER_NAMES
    from dsteleop.robot.scene import SceneGeometry, ScenePoses, VisualGeometry
    from dsteleop.robot.scripted import RunResult, goal_seeking_step, noise_free, run_autonomous
    from dsteleop.robot.task import (
        EventKind,
        Outcome,
        Phase,
        PickPlaceTask,
        TaskConfig,
        TaskEvent,
    )
    from dsteleop.robot.world import UTENSIL_NAMES

_EXPORTS = {
    "Contact": "arm",
    "RobotConfig": "arm",
    "BulletArmState": "arm",
    "Workspace": "arm",
    "EnvConfig": "env",
    "KitchenEnv": "env",
    "FINGER_NAMES": "hand_urdf",
    "SceneGeometry": "scene",
    "ScenePoses": "scene",
    "VisualGeometry": "scene",
    "RunResult": "scripted",
    "goal_seeking_step": "scripted",
    "noise_free": "scripted",
    "run_autonomous": "scripted",
    "EventKind": "task",
    "Outcome": "task",
    "Phase": "task",
    "PickPlaceTask": "task",
    "TaskConfig": "task",
    "TaskEvent": "task",
    "UTENSIL_NAMES": "world",
}

__all__ = [
    "FINGER_NAMES",
    "UTENSIL_NAMES",
    "BulletArmState",
    "Contact",
    "EnvConfig",
    "EventKind",
    "KitchenEnv",
    "Outcome",
    "Phase",
    "PickPlaceTask",
    "RobotConfig",
    "RunResult",
    "SceneGeometry",
    "ScenePoses",
    "TaskConfig",
    "TaskEvent",
    "VisualGeometry",
    "Workspace",
    "goal_seeking_step",
    "noise_free",
    "run_autonomous",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'dsteleop.robot' has no attribute {name!r}")
    return getattr(importlib.import_module(f"dsteleop.robot.{module}"), name)
