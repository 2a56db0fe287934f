"""How close does the palm come to a still pose? The steady-state error of each robot.

For each robot and each still goal (palm down, in free air above the table: the grasp
approach's pre-grasp poses above the three pockets and the place pose above the bin), reset
the kitchen and drive the palm for `--seconds` with either

    command  the pose itself, every tick (`set_target(goal)`: the arm's own tracking), or
    seek     the goal-seeking policy from the achieved palm (`robot.scripted`, alpha = 1:
             X_next = integrate(X_achieved, sat(K (X_goal - X_achieved)), dt), as the loop),

and report the palm's distance to the goal at the end (the mean of the last 0.5 s) and the
arm's joint sag (commanded joint targets minus measured joints, largest) [mm, mrad]. With
`--no-gravity-compensation` the arm is as it was before it held its own weight.

    .venv/bin/python scripts/steady_state.py                 # every shipped robot
    .venv/bin/python scripts/steady_state.py --robot panda --no-gravity-compensation
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from dsteleop.arbitration import HandState
from dsteleop.robot.arm import RobotConfig
from dsteleop.robot.bullet import pb
from dsteleop.robot.check import hold_still
from dsteleop.robot.description import load_description, shipped_robots
from dsteleop.robot.env import R_PALM_DOWN, EnvConfig, KitchenEnv
from dsteleop.robot.reach import task_placement
from dsteleop.robot.scripted import noise_free
from dsteleop.robot.world import BIN_CENTER_M, pocket_center_m

#: Still goals, scene frame: 0.45 m above the table over each pocket (the iiwa hand's
#: fingertips clear the utensils' tops at ~0.29 m by 6 cm; lower, they touch them) and the
#: place pose above the bin; each robot's placement stands them in its base frame.
GOALS = {
    **{f"above pocket {i}": pocket_center_m(i) + np.array([0.0, -0.02, 0.44]) for i in range(3)},
    "place": np.array([BIN_CENTER_M[0], BIN_CENTER_M[1], 0.45]),
}


def run(robot: str, goal_name: str, how: str, seconds: float, gc: bool) -> dict[str, float]:
    desc = load_description(robot)
    cfg = EnvConfig(description=desc, robot=RobotConfig(gravity_compensation=gc))
    placement = task_placement(desc, cfg.robot)
    with KitchenEnv(noise_free(cfg)) as env:
        p_goal, R_goal = placement.pose(GOALS[goal_name], R_PALM_DOWN)
        goal = HandState(p_goal, R_goal, np.ones(len(desc.fingers)))
        sags: list[float] = []

        def sag(_state: object) -> None:  # the arm exists once hold_still has reset the env
            arm = [env.robot._r.joints[n].index for n in desc.arm_joints]
            joints = pb.getJointStates(env.robot.body, arm, physicsClientId=env.client)
            q = np.array([j[0] for j in joints])
            sags.append(float(np.abs(env.robot._q_arm_cmd - q).max()))

        errs = hold_still(env, goal, how, sag, seconds)
        return {"error_mm": 1e3 * float(np.mean(errs)), "sag_mrad": 1e3 * float(np.mean(sags))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", help="robot (default: every shipped robot)")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument(
        "--no-gravity-compensation",
        action="store_true",
        help="as before the arm held its own weight up (RobotConfig.gravity_compensation)",
    )
    args = ap.parse_args()
    gc = not args.no_gravity_compensation
    for robot in args.robot or shipped_robots():
        for how in ("command", "seek"):
            rows = {g: run(robot, g, how, args.seconds, gc) for g in GOALS}
            worst = max(r["error_mm"] for r in rows.values())
            line = {
                "robot": robot,
                "how": how,
                "gravity_compensation": gc,
                "worst_error_mm": round(worst, 2),
                "goals": {g: {k: round(v, 2) for k, v in r.items()} for g, r in rows.items()},
            }
            sys.stdout.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
