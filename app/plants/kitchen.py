"""The PyBullet kitchen (robot + world + pick-and-place task) as a `ports.Plant`.

A thin adapter from `dsteleop.robot.env.KitchenEnv`: `apply(X_next)` commands the pose and
openness, steps one loop period of physics and the task (1/rate s: the world keeps the
loop's time, whatever its rate; `robot.arm.RobotConfig.for_period`), and reports the
achieved palm state and the task's own typed phase, events and outcome. Everything needed
to rebuild the same plant (utensil, seed, goal noise, control period) is in `describe()`,
which recordings store, so `plant_from_meta` gives replays the same world and the same
noisy goals.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dsteleop.app.ports import PlantStep
from dsteleop.arbitration import HandState
from dsteleop.robot.arm import CONTROL_DT_S, RobotConfig
from dsteleop.robot.env import EnvConfig, KitchenEnv
from dsteleop.robot.hand_urdf import FINGER_NAMES
from dsteleop.robot.scene import SceneGeometry
from dsteleop.robot.task import Phase
from dsteleop.robot.world import UTENSIL_NAMES


class KitchenPlant:
    """Robot and task for the loop.

    Args:
        utensil: the utensil to pick (one of `UTENSIL_NAMES`).
        seed: seed of the goal noise.
        goal_noise_m: std-dev of the noise on each goal position the robot knows [m]
            (None: the task's default).
        goal_noise_rad: std-dev of the rotation noise on each goal [rad] (None: default).
        export_scene: compute per-tick link poses for a viewer.
        time_limit_s: a trial without an outcome after this long fails (`timeout`) [s]
            (None: the task's default).
        control_dt_s: the loop's period [s]: each `apply` advances the world this much
            (None: the robot's default, 1/30 s).
    """

    finger_names: tuple[str, ...] = FINGER_NAMES

    def __init__(
        self,
        utensil: str = "spoon",
        seed: int = 0,
        goal_noise_m: float | None = None,
        goal_noise_rad: float | None = None,
        export_scene: bool = False,
        time_limit_s: float | None = None,
        control_dt_s: float | None = None,
    ) -> None:
        cfg = EnvConfig()
        if control_dt_s is not None:
            cfg = dataclasses.replace(cfg, robot=RobotConfig.for_period(control_dt_s))
        task = cfg.task
        if time_limit_s is not None:
            task = dataclasses.replace(task, timeout_s=float(time_limit_s))
        if goal_noise_m is not None:
            task = dataclasses.replace(task, goal_noise_pos_m=float(goal_noise_m))
        if goal_noise_rad is not None:
            task = dataclasses.replace(task, goal_noise_rot_rad=float(goal_noise_rad))
        self.config = dataclasses.replace(cfg, task=task)
        self.utensil = utensil
        self.seed = seed
        self.export_scene = export_scene
        self.env = KitchenEnv(self.config)

    # --- Plant interface ---------------------------------------------------------------

    def reset(self, utensil: str | None = None) -> HandState:
        if utensil is not None:
            self.utensil = utensil
        if self.env.config != self.config:
            self.env.close()
            self.env = KitchenEnv(self.config)
        state = self.env.reset(self.utensil, self.seed)
        return state.palm

    def goal(self) -> HandState | None:
        task = self.env.task
        return None if task.phase == Phase.DONE else task.goal

    def apply(self, X_next: HandState) -> PlantStep:
        self.env.set_target(X_next.position, X_next.rotation, X_next.openness)
        state = self.env.step()
        task = self.env.task
        return PlantStep(
            X_current=state.palm,
            phase=task.phase,
            events=tuple(self.env.last_events),
            outcome=task.outcome,
            scene=self.env.poses() if self.export_scene else None,
        )

    def set_goal_noise(self, sigma_m: float) -> None:
        """New goal noise; takes effect at the next task reset (goals are drawn at reset)."""
        self.config = dataclasses.replace(
            self.config, task=dataclasses.replace(self.config.task, goal_noise_pos_m=float(sigma_m))
        )

    def describe(self) -> dict[str, Any]:
        task = self.env.task
        return {
            "kind": "kitchen",
            "utensil": self.utensil,
            "seed": self.seed,
            "goal_noise_m": self.config.task.goal_noise_pos_m,
            "goal_noise_rad": self.config.task.goal_noise_rot_rad,
            "task": dataclasses.asdict(self.config.task),
            "pick_known": _pose(task.pick_known),
            "place_known": _pose(task.place_known),
            "pick_true": _pose(task.pick_true),
            "place_true": _pose(task.place_true),
            "utensils": list(UTENSIL_NAMES),
            "control_dt_s": self.config.robot.control_dt_s,
        }

    def scene(self) -> SceneGeometry:
        return self.env.geometry()

    def close(self) -> None:
        self.env.close()

    # --- for the demo operator ----------------------------------------------------------

    def true_goals(self) -> tuple[HandState, HandState]:
        """The true pick and place palm poses (open hand), noise-free, as a person watching
        the scene sees them: the pick is the grasp pose of the utensil where it is now (the
        task's `pick_true` until the utensil moves, e.g. pushed by a failed grasp)."""
        task = self.env.task
        n = len(FINGER_NAMES)
        return (
            HandState(*self.env.grasp_pose(), np.ones(n)),
            HandState(*task.place_true, np.ones(n)),
        )


def _pose(pose: tuple[Any, Any]) -> dict[str, list[float]]:
    p, R = pose
    return {"p": [float(x) for x in p], "R": [float(x) for x in R.ravel()]}


def plant_from_meta(meta: dict[str, Any], export_scene: bool = False) -> KitchenPlant:
    """The plant a recording describes (defaults for what it does not say)."""
    plant = KitchenPlant(
        utensil=str(meta.get("utensil", "spoon")),
        seed=int(meta.get("seed", 0)),
        goal_noise_m=meta.get("goal_noise_m"),
        goal_noise_rad=meta.get("goal_noise_rad"),
        export_scene=export_scene,
        time_limit_s=(meta.get("task") or {}).get("timeout_s"),
        # Sessions before the world kept the loop's rate stepped 1/30 s a tick whatever it was.
        control_dt_s=float(meta.get("control_dt_s") or CONTROL_DT_S),
    )
    return plant
