"""The kitchen pick-and-place task as a `ports.Task`, judging any robot that can reach it.

The task owns a PyBullet world (`robot.env.KitchenEnv`: table, holder, utensils, bin, and a
robot of the judged robot's description) and `robot.task.PickPlaceTask` (goals, phases,
events, outcome). How it judges a robot (docs/ARCHITECTURE.md):

    same world   the judged robot is this world's robot (`simulated_kitchen`: a
                 `plants.simulated.SimulatedRobot` sharing the env). `Robot.apply` stepped
                 the physics; `update` only observes: the utensil, the contacts, the task.
    twin         any other robot (a linked one): this world's robot is its twin. `update`
                 drives the twin's arm joints to the measured ones (position motors, one loop
                 period of physics) and its fingers by the measured finger command (so they
                 grip this world's utensil with the hand's force), then observes as above.
                 The utensil moves with the twin, so the outcome is the twin's: close to
                 the far end's where its world is this one (the reference far end,
                 `robot-sim`), an estimate of the real scene for a real arm.

A robot that is not told its utensil (`infer`, `--goal infer`) chooses among `candidates()`:
every utensil in the holder as it perceives them through its camera (`robot.perception`: the
same error model draws each candidate's known pose and gives the belief its uncertainty), and
the bin in the place phase; the task's utensil is the one the person grasps
(`robot.task`). `--goal-noise M` makes that error isotropic, M on every axis, as a told
goal's always was.

Everything that rebuilds the same task (utensil, seed, goal noise, control period, timeout,
whether the robot is told, its perception) is in `describe()`, which recordings store, so
`task_from_meta` gives replays the same world and the same noisy goals.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dsteleop.app.plants.described import joint_names_of
from dsteleop.app.plants.simulated import SimulatedRobot
from dsteleop.app.ports import RobotState, TaskStep
from dsteleop.arbitration import HandState
from dsteleop.robot.arm import CONTROL_DT_S, RobotConfig
from dsteleop.robot.description import RobotDescription, load_description
from dsteleop.robot.env import EnvConfig, KitchenEnv
from dsteleop.robot.perception import PerceptionError
from dsteleop.robot.placement import Placement
from dsteleop.robot.scene import SceneGeometry
from dsteleop.robot.task import INFER, Candidates, Phase
from dsteleop.robot.world import UTENSIL_NAMES


class KitchenTask:
    """The kitchen task (module docstring).

    Args:
        description: the judged robot's description (its twin, or itself, stands here).
        utensil: the utensil to pick (one of `UTENSIL_NAMES`); with `infer`, the one the person
            means to pick (the demo person's), never read by the robot.
        seed: seed of the goal noise.
        goal_noise_m: std-dev of the noise on each goal position the robot knows [m], per
            axis (None: the task's default, or with `infer` the robot camera's anisotropic
            `PerceptionError()`).
        goal_noise_rad: std-dev of the rotation noise on each goal [rad] (None: default).
        export_scene: compute per-tick link poses for a viewer.
        time_limit_s: a trial without an outcome after this long fails (`timeout`) [s]
            (None: the task's default).
        control_dt_s: the loop's period [s]: each tick advances the world this much (None:
            the robot's default, 1/30 s).
        twin: judge a robot outside this world through its twin (module docstring).
        infer: the robot is not told its utensil (module docstring).
        perception: with `infer`, how the robot perceives the candidates (None:
            `PerceptionError()`, or isotropic when `goal_noise_m` is given).
        placement: where the scene stands in the robot's base frame (`robot.placement`;
            None: the description's, `robot.reach.task_placement`; a replay: the recorded).
    """

    def __init__(
        self,
        description: RobotDescription | None = None,
        utensil: str = "spoon",
        seed: int = 0,
        goal_noise_m: float | None = None,
        goal_noise_rad: float | None = None,
        export_scene: bool = False,
        time_limit_s: float | None = None,
        control_dt_s: float | None = None,
        twin: bool = True,
        infer: bool = False,
        perception: PerceptionError | None = None,
        placement: Placement | None = None,
    ) -> None:
        cfg = EnvConfig(description=description or load_description("iiwa"), placement=placement)
        if control_dt_s is not None:
            cfg = dataclasses.replace(cfg, robot=RobotConfig.for_period(control_dt_s))
        task = cfg.task
        if time_limit_s is not None:
            task = dataclasses.replace(task, timeout_s=float(time_limit_s))
        if goal_noise_m is not None:
            task = dataclasses.replace(task, goal_noise_pos_m=float(goal_noise_m))
        if goal_noise_rad is not None:
            task = dataclasses.replace(task, goal_noise_rot_rad=float(goal_noise_rad))
        if perception is None:
            perception = (
                PerceptionError()
                if goal_noise_m is None
                else PerceptionError.isotropic(task.goal_noise_pos_m, task.goal_noise_rot_rad)
            )
        #: How a robot not told its utensil perceives the candidates (whether it is now).
        self.perception = perception
        self.config = dataclasses.replace(
            cfg, task=task, infer=infer, perception=perception if infer else None
        )
        self.utensil = utensil
        self.seed = seed
        self.export_scene = export_scene
        self.twin = twin
        self.env = KitchenEnv(self.config)

    # --- Task interface ----------------------------------------------------------------

    def reset(self, utensil: str | None = None) -> None:
        """A new trial: `utensil` a utensil's name tells the robot that one (the person's
        too); "infer" tells it none (the person keeps its utensil); None: as before."""
        if utensil == INFER:
            self.config = dataclasses.replace(self.config, infer=True, perception=self.perception)
        elif utensil is not None:
            self.utensil = utensil
            self.config = dataclasses.replace(self.config, infer=False, perception=None)
        self.env.config = self.config  # a new goal noise (the same robot and world)
        self.env.reset(self.utensil, self.seed)

    def goal(self) -> HandState | None:
        task = self.env.task
        if task.phase == Phase.DONE or (task.phase == Phase.PICK and not task.told):
            return None
        return task.goal

    def candidates(self) -> Candidates | None:
        return self.env.task.candidates()

    def update(self, state: RobotState) -> TaskStep:
        if self.twin:
            desc = self.config.description
            measured = dict(zip(joint_names_of(desc), state.joints.tolist(), strict=True))
            # The arm follows the measured joints; the fingers take the measured openness (the
            # finger command), so they grip this world's utensil with the hand's force, as the
            # far hand grips what is in front of it. Held at the far fingers' measured angles
            # they would touch it with no force, and it slipped in transport.
            self.env.follow({j: measured[j] for j in desc.arm_joints}, state.X.openness)
        self.env.observe_task()
        task = self.env.task
        return TaskStep(
            phase=task.phase,
            events=tuple(self.env.last_events),
            outcome=task.outcome,
            scene=self.env.poses() if self.export_scene else None,
        )

    def set_goal_noise(self, sigma_m: float) -> None:
        """New goal noise (isotropic, also for a robot not told its utensil); takes effect at
        the next task reset (goals are drawn at reset)."""
        task = dataclasses.replace(self.config.task, goal_noise_pos_m=float(sigma_m))
        self.perception = PerceptionError.isotropic(
            float(sigma_m), self.perception.rotation_sigma_rad
        )
        perception = self.perception if self.config.infer else None
        self.config = dataclasses.replace(self.config, task=task, perception=perception)

    def describe(self) -> dict[str, Any]:
        task = self.env.task
        perception = self.config.perception
        return {
            "kind": "kitchen",
            "utensil": self.utensil,
            # What the robot is told: a utensil, or "infer" (it chooses among candidates).
            "goal": INFER if self.config.infer else self.utensil,
            "perception": None if perception is None else perception.to_dict(),
            "candidates_known": {n: _pose(pose) for n, pose in task.candidates_known.items()},
            "seed": self.seed,
            "goal_noise_m": self.config.task.goal_noise_pos_m,
            "goal_noise_rad": self.config.task.goal_noise_rot_rad,
            "task": dataclasses.asdict(self.config.task),
            "pick_known": _pose(task.pick_known),
            "place_known": _pose(task.place_known),
            "pick_true": _pose(task.pick_true),
            "place_true": _pose(task.place_true),
            "utensils": list(UTENSIL_NAMES),
            # What the page's Utensil menu offers: infer, or tell the robot a utensil.
            "goals": [INFER, *UTENSIL_NAMES],
            "control_dt_s": self.config.robot.control_dt_s,
            "robot": self.config.description.name,
            # Where the scene stood in the robot's base frame (a replay stands it there too).
            "placement": self.env.placement.to_dict(),
            "judged": "twin" if self.twin else "same world",
        }

    def scene(self) -> SceneGeometry:
        return self.env.geometry()

    def close(self) -> None:
        self.env.close()

    def true_goals(self, utensil: str | None = None) -> tuple[HandState, HandState]:
        """The true pick and place palm poses (open hand), noise-free, as a person watching
        the scene sees them: the pick is the grasp pose of `utensil` (None: the task's) where
        it is now (the task's `pick_true` until the utensil moves, e.g. pushed by a failed
        grasp)."""
        task = self.env.task
        n = len(self.config.description.fingers)
        return (
            HandState(*self.env.grasp_pose(utensil), np.ones(n)),
            HandState(*task.place_true, np.ones(n)),
        )


def simulated_kitchen(
    description: RobotDescription | None = None, **task_options: Any
) -> tuple[SimulatedRobot, KitchenTask]:
    """A simulated robot and the kitchen task in one world (module docstring: same world);
    `task_options` are `KitchenTask`'s."""
    task = KitchenTask(description, twin=False, **task_options)
    return SimulatedRobot(task.env), task


def _pose(pose: tuple[Any, Any]) -> dict[str, list[float]]:
    p, R = pose
    return {"p": [float(x) for x in p], "R": [float(x) for x in R.ravel()]}


def task_options_from_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """The `KitchenTask` options a recording's task metadata gives (defaults for what it
    does not say)."""
    return {
        "utensil": str(meta.get("utensil", "spoon")),
        "seed": int(meta.get("seed", 0)),
        "goal_noise_m": meta.get("goal_noise_m"),
        "goal_noise_rad": meta.get("goal_noise_rad"),
        "time_limit_s": (meta.get("task") or {}).get("timeout_s"),
        # Sessions before the world kept the loop's rate stepped 1/30 s a tick whatever it was.
        "control_dt_s": float(meta.get("control_dt_s") or CONTROL_DT_S),
        # Sessions before goal inference told the robot its utensil.
        "infer": meta.get("goal") == INFER,
        "perception": (
            None
            if meta.get("perception") is None
            else PerceptionError.from_dict(meta["perception"])
        ),
        # Sessions before placements stood the scene where the description does.
        "placement": (
            None if meta.get("placement") is None else Placement.from_dict(meta["placement"])
        ),
    }
