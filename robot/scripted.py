"""The scripted autonomous run: alpha = 1, the goal-seeking policy alone, noise-free goals.

It is the smoke test that the world is solvable, and it drives the robot exactly as the
control loop will at alpha = 1, with the arbitration's own SE(3) operations and gains:

    U_robot   = saturate(K_r * diff(X_goal, X_current), v_max)      (ArbitrationConfig)
    X_next    = integrate(X_current, U_robot, dt)                    eq (2) with alpha = 1
    env.set_target(X_next.position, X_next.rotation, X_next.openness)
    X_current = env.step().palm

which is what `make_arbiter("autonomous")` computes for X_next (U_out = U_robot); the
policy is written out here so the smoke test depends only on `arbitration.se3`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

from dsteleop.arbitration.config import ArbitrationConfig
from dsteleop.arbitration.se3 import HandState, diff, integrate, saturate
from dsteleop.robot.env import EnvConfig, KitchenEnv
from dsteleop.robot.task import Outcome, TaskEvent


@dataclass(frozen=True)
class RunResult:
    """Result of one run.

    Attributes:
        utensil: the utensil.
        seed: the seed of the goal noise.
        outcome: how it ended.
        events: every task event, in order.
        ticks: control ticks simulated.
        sim_time_s: simulated time [s].
        wall_time_s: wall-clock time the run took [s].
    """

    utensil: str
    seed: int
    outcome: Outcome
    events: tuple[TaskEvent, ...]
    ticks: int
    sim_time_s: float
    wall_time_s: float


def noise_free(config: EnvConfig | None = None) -> EnvConfig:
    """`config` with the goal noise set to zero."""
    cfg = config or EnvConfig()
    return dataclasses.replace(
        cfg, task=dataclasses.replace(cfg.task, goal_noise_pos_m=0.0, goal_noise_rot_rad=0.0)
    )


def goal_seeking_step(
    X_current: HandState,
    X_goal: HandState,
    dt_s: float,
    config: ArbitrationConfig | None = None,
) -> HandState:
    """X_next of the goal-seeking policy alone (alpha = 1), see the module docstring."""
    cfg = config or ArbitrationConfig()
    F = X_current.n_fingers
    U = saturate(cfg.gains(F) * diff(X_goal, X_current), cfg.v_max(F))
    return integrate(X_current, U, dt_s)


def run_autonomous(
    env: KitchenEnv,
    utensil: str,
    seed: int = 0,
    arbitration: ArbitrationConfig | None = None,
) -> RunResult:
    """Reset `env` for `utensil` and run the autonomous policy until the task has an outcome.

    The environment's own task config decides the goal noise and the timeout; use
    `noise_free()` for the smoke test.
    """
    t0 = time.monotonic()
    state = env.reset(utensil=utensil, seed=seed)
    task = env.task
    X = state.palm
    ticks = 0
    while task.outcome is None:
        X_next = goal_seeking_step(X, task.goal, env.dt_s, arbitration)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
        ticks += 1
    return RunResult(
        utensil,
        seed,
        task.outcome,
        tuple(task.events),
        ticks,
        ticks * env.dt_s,
        time.monotonic() - t0,
    )
