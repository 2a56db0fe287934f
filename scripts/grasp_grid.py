"""How robust is the robot's grasp? Close the hand at palm poses off the true grasp pose, carry
the utensil to the bin, and count the utensils still held.

Each case: reset the noise-free kitchen, drive the palm (the goal-seeking policy at the loop's
limits, alpha = 1) to the true grasp pose plus an offset with the hand open (5 s), close the
hand there (1.3 s), then carry it to the place pose, either with the same policy (`policy`:
a velocity step to the 0.25 m/s limit, the hardest start) or along a minimum-jerk path at a
peak of 0.15 m/s (`minjerk`: the demo person's hand), and hold 1 s. Held: the thumb and a
closed finger still touch the utensil and it is within 0.25 m of the palm. Offsets are in
the grasp frame (x along the finger row, y across the grip, z down the handle):

    axes    each axis alone: 0.5-2 cm in x and y, 0.5-1 cm in z, 0.05-0.1 rad about each
            axis (both signs), and four 7 mm diagonals in x-y (37 cases)
    random  40 draws of the task's goal noise (1 cm and 0.05 rad per axis, seed 123): the
            poses a robot closes at on its own, noisy goal

    .venv/bin/python scripts/grasp_grid.py --utensil spoon --grid axes --carry policy

Prints one line per case (grip force after closing, the largest shift of the utensil's
centre of mass relative to the palm during the carry) and a summary.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import HandState
from dsteleop.arbitration.se3 import so3_exp, so3_log
from dsteleop.robot.bullet import pb
from dsteleop.robot.env import KitchenEnv
from dsteleop.robot.scripted import goal_seeking_step, noise_free

Array = NDArray[np.float64]
Case = tuple[str, Array, Array]


def cases(grid: str) -> Iterator[Case]:
    zero = np.zeros(3)
    if grid == "random":
        rng = np.random.default_rng(123)
        for i in range(40):
            dp, dr = rng.normal(0.0, 0.01, 3), rng.normal(0.0, 0.05, 3)
            yield f"rand{i} ({dp[0] * 100:+.1f},{dp[1] * 100:+.1f},{dp[2] * 100:+.1f}) cm", dp, dr
        return
    yield "0", zero, zero
    for ax, name in enumerate("xyz"):
        for v in (0.005, 0.01, 0.015, 0.02) if name != "z" else (0.005, 0.01):
            for sign in (1, -1):
                dp = zero.copy()
                dp[ax] = sign * v
                yield f"d{name}={sign * v * 100:+.1f}cm", dp, zero
    for ax, name in enumerate("xyz"):
        for v in (0.05, 0.1):
            for sign in (1, -1):
                dr = zero.copy()
                dr[ax] = sign * v
                yield f"r{name}={sign * v:+.2f}rad", zero, dr
    for dx, dy in ((0.007, 0.007), (-0.007, 0.007), (0.007, -0.007), (-0.007, -0.007)):
        yield f"dxy={dx * 100:+.1f},{dy * 100:+.1f}cm", np.array([dx, dy, 0.0]), zero


def trial(env: KitchenEnv, utensil: str, dp: Array, dr: Array, carry: str) -> dict[str, Any]:
    env.reset(utensil, 0)
    p_true, R_true = env.task.pick_true
    p_goal, R_goal = p_true + R_true @ dp, R_true @ so3_exp(dr)
    state = env.state()
    X = state.palm

    def command(X_next: HandState) -> None:
        nonlocal X, state
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        state = env.step()
        X = state.palm

    for k in range(190):  # 5 s to the pose, open; then 1.3 s closing
        g = np.ones(4) if k < 150 else np.zeros(4)
        command(goal_seeking_step(X, HandState(p_goal, R_goal, g), env.dt_s))
    uid = env.world.utensils[utensil]
    grip_n = sum(c[9] for c in pb.getContactPoints(bodyA=env.robot.body, bodyB=uid))
    p_u = env.utensil_pose()[0]
    u0 = X.rotation.T @ (p_u - X.position)
    p_place, R_place = env.task.place_true
    closed = np.zeros(4)
    path: Callable[[int], HandState]
    if carry == "policy":
        n = 150

        def path(k: int) -> HandState:
            return goal_seeking_step(X, HandState(p_place, R_place, closed), env.dt_s)

    else:
        p0, R0 = X.position.copy(), X.rotation.copy()
        d, w = p_place - p0, so3_log(R_place @ R0.T)
        T = 1.875 * float(np.linalg.norm(d)) / 0.15
        n = int(T * 30) + 30

        def path(k: int) -> HandState:
            u = min((k + 1) / 30 / T, 1.0)
            s = u**3 * (10 - 15 * u + 6 * u * u)
            return HandState(p0 + s * d, so3_exp(s * w) @ R0, closed)

    shift = 0.0
    for k in range(n):
        command(path(k))
        u = X.rotation.T @ (env.utensil_pose()[0] - X.position)
        shift = max(shift, float(np.linalg.norm(u - u0)))
    u = X.rotation.T @ (env.utensil_pose()[0] - X.position)
    held = bool(env._observe(state).held and np.linalg.norm(u) < 0.25)
    return {"held": held, "grip_n": grip_n, "shift_m": shift}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--utensil", default="spoon")
    ap.add_argument("--grid", choices=("axes", "random"), default="axes")
    ap.add_argument("--carry", choices=("policy", "minjerk"), default="policy")
    args = ap.parse_args()
    rows = []
    with KitchenEnv(noise_free()) as env:
        for name, dp, dr in cases(args.grid):
            r = trial(env, args.utensil, dp, dr, args.carry)
            rows.append(r)
            sys.stdout.write(
                f"{name:28s} held={r['held']!s:5s} grip={r['grip_n']:5.1f} N "
                f"carry shift={r['shift_m'] * 100:5.1f} cm\n"
            )
            sys.stdout.flush()
    grip = np.array([r["grip_n"] for r in rows])
    sys.stdout.write(
        f"{args.utensil} {args.grid} {args.carry}: held {sum(r['held'] for r in rows)}/{len(rows)}"
        f", grip force median {np.median(grip):.1f} N (min {grip.min():.1f} N)\n"
    )


if __name__ == "__main__":
    main()
