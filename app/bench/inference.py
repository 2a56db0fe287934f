"""Bench group `inference`: what goal inference costs the live loop's tick.

Two demo loops built as `dsteleop run --source demo` builds them (the PyBullet robot and
kitchen, the demo person through the tracking pipeline, DS), one told its utensil and one
inferring it (`--goal infer`: `Task.candidates`, the belief's update, its confidence and
MAP goal every tick), ticked headless on their manual clocks in alternation, tick by tick, so
that both see the same load on the machine. Each tick is timed from the loop's own call to
its return (`TeleopLoop.tick`: requests, input, the goal, the arbitration, the robot's
physics, the task, the record). 600 ticks each (20 s of the task; 150 with --quick), after
30 ticks of warm-up each that are not counted; a loop whose task ended is reset.

    loop_tick_ms_told       median, p95, p99 of the told loop's ticks [ms]
    loop_tick_ms_infer      the same for the inferring loop
    loop_inference_cost_ms  the difference of the medians, and of the p95s [ms] (the two
                            loops' robots do not move alike: the inferring one seeks the MAP,
                            and physics with contacts costs more, so this includes that)
    loop_goal_ms            within the inferring loop's ticks, the inference itself (the task's
                            candidates, the belief's update, confidence and MAP goal: the
                            record's `timing.goal_ms`): median, p95, p99 [ms]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from dsteleop.app.compose import LoopOptions, build


def run(quick: bool = False) -> dict[str, Any]:
    ticks = 150 if quick else 600
    warm = 30
    told = build(LoopOptions.of("demo", utensil="ladle", seed=3), realtime=False)
    infer = build(LoopOptions.of("demo", goal="infer", utensil="ladle", seed=3), realtime=False)
    samples: dict[str, list[float]] = {"told": [], "infer": []}
    goal_ms: list[float] = []
    try:
        loops = {"told": told.loop, "infer": infer.loop}
        for loop in loops.values():
            loop.hand.start()
        k_of = dict.fromkeys(loops, 0)
        for k in range(warm + ticks):
            for name, loop in loops.items():
                if loop.outcome:  # the next trial
                    loop.controls.reset()
                t = k_of[name] / loop.config.rate_hz
                loop.clock.sleep_until(t)
                t0 = time.perf_counter()
                record = loop.tick(t)
                dt = time.perf_counter() - t0
                k_of[name] += 1
                if k >= warm:
                    samples[name].append(dt)
                    if "goal_ms" in record.timing:
                        goal_ms.append(record.timing["goal_ms"])
    finally:
        told.close()
        infer.close()
    out: dict[str, Any] = {}
    for name, s in samples.items():
        a = np.asarray(s) * 1e3
        out[f"loop_tick_ms_{name}"] = {
            "median": round(float(np.median(a)), 3),
            "p95": round(float(np.percentile(a, 95)), 3),
            "p99": round(float(np.percentile(a, 99)), 3),
            "n": int(a.size),
        }
    t, i = out["loop_tick_ms_told"], out["loop_tick_ms_infer"]
    out["loop_inference_cost_ms"] = {
        "median": round(i["median"] - t["median"], 3),
        "p95": round(i["p95"] - t["p95"], 3),
    }
    g = np.asarray(goal_ms)
    out["loop_goal_ms"] = {
        "median": round(float(np.median(g)), 3),
        "p95": round(float(np.percentile(g, 95)), 3),
        "p99": round(float(np.percentile(g, 99)), 3),
        "n": int(g.size),
    }
    return out
