"""`dsteleop bench --only robot`: the cost of one robot control tick, measured in contact.

One tick is what the loop pays per 30 Hz period: `env.set_target(...)` (workspace clamp, IK,
motor targets) + `env.step()` (physics substeps for 1/30 s, contacts, grasp helper, task
bookkeeping, the returned state). The scripted autonomous pick-and-place drives the robot;
`robot_tick_ms` keeps only the ticks after which a robot link touches the utensil (closing
on it, holding it, releasing it), `robot_tick_free_ms` the others. `robot_tick_cpu_ms` is the
same contact ticks in thread CPU time: on a shared machine it shows the tick's own cost
while the wall-clock figures also carry the waits for a core.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

log = logging.getLogger(__name__)


def _ms(samples_s: list[float]) -> dict[str, float]:
    a = np.asarray(samples_s, dtype=np.float64) * 1e3
    if a.size == 0:
        return {"median": float("nan"), "p95": float("nan"), "p99": float("nan"), "n": 0}
    return {
        "median": round(float(np.median(a)), 4),
        "p95": round(float(np.percentile(a, 95)), 4),
        "p99": round(float(np.percentile(a, 99)), 4),
        "n": int(a.size),
    }


def run(quick: bool) -> dict[str, Any]:
    """Time robot ticks during scripted pick-and-place runs (one utensil if `quick`)."""
    from dsteleop.robot.env import KitchenEnv
    from dsteleop.robot.scripted import goal_seeking_step, noise_free
    from dsteleop.robot.world import UTENSIL_NAMES

    utensils = UTENSIL_NAMES[:1] if quick else UTENSIL_NAMES
    contact: list[float] = []
    contact_cpu: list[float] = []
    free: list[float] = []
    outcomes: dict[str, bool] = {}
    with KitchenEnv(noise_free()) as env:
        cfg = env.config.robot
        for utensil in utensils:
            X = env.reset(utensil=utensil, seed=0).palm
            uid = env.world.utensils[utensil]
            while env.task.outcome is None:
                X_next = goal_seeking_step(X, env.task.goal, env.dt_s)
                t0, c0 = time.perf_counter(), time.thread_time()
                env.set_target(X_next.position, X_next.rotation, X_next.openness)
                state = env.step()
                dt, dc = time.perf_counter() - t0, time.thread_time() - c0
                X = state.palm
                touching = any(c.other_body == uid for c in state.contacts)
                (contact if touching else free).append(dt)
                if touching:
                    contact_cpu.append(dc)
            outcomes[utensil] = env.task.outcome.success
    log.info("robot bench: %d contact ticks, %d free ticks", len(contact), len(free))
    return {
        "robot_tick_ms": _ms(contact),
        "robot_tick_cpu_ms": _ms(contact_cpu),
        "robot_tick_free_ms": _ms(free),
        "robot_physics": {
            "substeps": cfg.substeps,
            "solver_iterations": cfg.solver_iterations,
            "physics_dt_s": round(cfg.physics_dt_s, 6),
        },
        "robot_scripted_success": outcomes,
    }
