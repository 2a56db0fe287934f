"""A PyBullet robot of any description (`robot.description`) as a `ports.Robot`.

It lives in a `robot.env.KitchenEnv`: the world the kitchen task judges it in, when the two
share it (`plants.kitchen.simulated_kitchen`: the utensil is physical), or a world of its own
(`owns_world=True`: e.g. the far end of a link, with nothing else running in it).

`apply(X_cmd, seq, now)` clamps and solves the command (`robot.arm`), steps one loop period
of physics (1/rate s: `robot.arm.RobotConfig.for_period`) and stamps the new state with
`now`; `state(now)` is that state: palm pose, finger openness (the commanded set-point, as
`robot.arm` explains) and every joint's position in `joint_names` order (the arm's joints,
then the finger joints).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from dsteleop.app.plants.described import joint_names_of, joint_units_of, limits_of
from dsteleop.app.ports import RobotLimits, RobotState
from dsteleop.arbitration import HandState
from dsteleop.robot.description import RobotDescription
from dsteleop.robot.env import EnvConfig, KitchenEnv
from dsteleop.robot.scene import SceneGeometry


class SimulatedRobot:
    """A description's robot in a PyBullet world (module docstring).

    Args:
        env: the world it is in.
        owns_world: it resets the world itself at `reset` and closes it at `close` (a robot
            alone); False when a task shares the world and resets it (`Task.reset`).
        utensil: the utensil set up when it resets a world of its own.
    """

    def __init__(self, env: KitchenEnv, owns_world: bool = False, utensil: str = "spoon") -> None:
        self.env = env
        self.desc = env.config.description
        self.owns_world = owns_world
        self._utensil = utensil
        self._stamp_s = 0.0
        self._joint_names = joint_names_of(self.desc)
        self._joint_units = joint_units_of(self.desc)
        self._limits = limits_of(self.desc)

    @classmethod
    def alone(
        cls, desc: RobotDescription, control_dt_s: float | None = None, utensil: str = "spoon"
    ) -> SimulatedRobot:
        """A robot in a world of its own (the kitchen's with `utensil`, nothing judging it)."""
        cfg = EnvConfig(description=desc)
        if control_dt_s is not None:
            from dsteleop.robot.arm import RobotConfig

            cfg = dataclasses.replace(cfg, robot=RobotConfig.for_period(control_dt_s))
        return cls(KitchenEnv(cfg), owns_world=True, utensil=utensil)

    @property
    def name(self) -> str:
        return self.desc.name

    @property
    def finger_names(self) -> tuple[str, ...]:
        return self.desc.finger_names

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    @property
    def joint_units(self) -> tuple[str, ...]:
        return self._joint_units

    @property
    def limits(self) -> RobotLimits:
        return self._limits

    def reset(self, now_s: float) -> RobotState:
        if self.owns_world:
            self.env.reset(self._utensil, 0)
        self._stamp_s = now_s
        return self._state()

    def apply(self, X_cmd: HandState, seq: int, now_s: float) -> None:
        self.env.set_target(X_cmd.position, X_cmd.rotation, X_cmd.openness)
        self.env.step_robot()
        self._stamp_s = now_s

    def state(self, now_s: float) -> RobotState | None:
        return self._state()

    def _state(self) -> RobotState:
        s = self.env.state()
        q = np.array([s.joint_positions_rad[n] for n in self._joint_names], dtype=np.float64)
        return RobotState(s.palm, q, self._stamp_s)

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "simulated",
            "name": self.desc.name,
            "control_dt_s": self.env.config.robot.control_dt_s,
            "description": self.desc.to_dict(),
        }

    def scene(self) -> SceneGeometry | None:
        return self.env.geometry()

    def close(self) -> None:
        if self.owns_world:
            self.env.close()
