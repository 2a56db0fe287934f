"""dsteleop.robot: a PyBullet KUKA iiwa with a four-finger hand and the kitchen pick-and-place task.

Public API (see docs/robot.md):
    KitchenEnv, EnvConfig            robot + world + task; reset / set_target / step / state,
                                     geometry() and poses() for a viewer
    RobotConfig, RobotState, Contact control settings and the per-tick read-back
    PickPlaceTask, TaskConfig, Phase, EventKind, TaskEvent, Outcome
    run_autonomous, goal_seeking_step, noise_free, RunResult   the scripted alpha = 1 run
    SceneGeometry, ScenePoses, VisualGeometry                  viewer export (no pybullet)
    FINGER_NAMES, UTENSIL_NAMES

Names are resolved lazily, so `import dsteleop.robot.scene` (what a viewer needs) never
loads PyBullet.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dsteleop.robot.arm import Contact, RobotConfig, RobotState, Workspace
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
    "RobotState": "arm",
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
    "Contact",
    "EnvConfig",
    "EventKind",
    "KitchenEnv",
    "Outcome",
    "Phase",
    "PickPlaceTask",
    "RobotConfig",
    "RobotState",
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
