"""`dsteleop bench --only sweep`: a small `dsteleop sim --sweep` on a local Ray cluster of 1
and then of 2 workers, in the same run, so the speed-up of the second worker shows.

The same sweep twice (`run_sweep`, each into a fresh temporary folder): 8 cells (goal noise,
delay and depth error at 2 levels each: 0 and the default grid's middle level) x the study's
four modes x 100 trajectories (`--quick`: 2 cells x 20 trajectories). `seconds` is the
sweep's wall time with its cluster's start; `cluster_start_s` is that start alone, and
`cells_s` the rest; `cell_seconds_summed` adds up each cell's own wall time in its worker
(it grows when the workers compete for cores). `speedup` is 1 worker's `seconds` over 2
workers', `speedup_without_start` the same without the clusters' starts. The machine's CPU
model and load are beside the figures (`machine`, `machine_after`): on a shared machine the
second worker only helps as much as a second core is free.
"""

from __future__ import annotations

import logging
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


def run(quick: bool) -> dict[str, Any]:
    from dsteleop.app.bench import machine
    from dsteleop.app.study.planar import SimConfig
    from dsteleop.app.study.sweep import AXES, Grid, default_levels, run_sweep
    from dsteleop.app.tasks.cluster import RayExecutor

    trajectories = 20 if quick else 100
    levels: dict[str, tuple[float, ...]] = {axis: (0.0, default_levels(axis)[1]) for axis in AXES}
    if quick:
        levels = {"goal": levels["goal"], "delay": (0.0,), "depth": (0.0,)}
    grid = Grid(levels)
    cfg = SimConfig(trajectories=trajectories, seed=0)
    out: dict[str, Any] = {
        "cells": len(grid.cells()),
        "grid": grid.to_dict(),
        "trajectories": trajectories,
        "modes": [m.value for m in cfg.modes],
    }
    results = {}
    for workers in (1, 2):
        log.info(
            "bench sweep: %d cells on a local Ray cluster of %d CPU(s)", len(grid.cells()), workers
        )
        load = machine()["load_average"]
        with tempfile.TemporaryDirectory(prefix="dsteleop-bench-sweep-") as tmp:
            t0 = time.perf_counter()
            res = run_sweep(cfg, grid, Path(tmp), partial(RayExecutor, workers=workers))
            seconds = time.perf_counter() - t0
        if res.failed or res.summary["computed"] != len(grid.cells()):
            raise RuntimeError(f"bench sweep: cells failed: {res.failed}")
        start = res.summary["cluster_start_s"]
        results[workers] = {
            "seconds": round(seconds, 2),
            "cluster_start_s": round(start, 2),
            "cells_s": round(seconds - start, 2),
            "cell_seconds_summed": round(
                sum(c["seconds"] for c in res.summary["cells"] if c["seconds"]), 2
            ),
            "load_average_before": load,
        }
    out["ray_1_worker"] = results[1]
    out["ray_2_workers"] = results[2]
    out["speedup"] = round(results[1]["seconds"] / results[2]["seconds"], 3)
    out["speedup_without_start"] = round(results[1]["cells_s"] / results[2]["cells_s"], 3)
    return {"sweep": out}
