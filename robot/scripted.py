"""The scripted autonomous run: alpha = 1, the goal-seeking policy alone, noise-free goals.

It is the smoke test that the world is solvable, and it drives the robot exactly as the
control loop does at alpha = 1: the autonomous arbiter (`arbitration.arbiters`) gives

    U_robot   = sat(K_r * diff(X_goal, X_current))                  (arbitration.policy)
    X_next    = integrate(X_current, U_robot, dt)                    eq (2) with alpha = 1
    env.set_target(X_next.position, X_next.rotation, X_next.openness)
    X_current = env.step().palm
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

from dsteleop.arbitration import ArbitrationInput, HandState, Mode, make_arbiter
from dsteleop.arbitration.config import ArbitrationConfig
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
    arbiter = make_arbiter(Mode.AUTONOMOUS, config)
    X = X_current
    _, step = arbiter.step(
        arbiter.initial_state(6 + X.n_fingers),
        ArbitrationInput(
            X_human=X,
            X_human_prev=X,
            X_human_start=X,
            X_current=X,
            X_prev=X,
            X_start=X,
            X_goal=X_goal,
            dt=dt_s,
        ),
    )
    return step.X_next


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
