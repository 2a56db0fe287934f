"""`dsteleop bench --only study`: the simulation study's wall time as a user runs it, the
default world and the objects world (the robot inferring the goal among 3 objects, 7 modes)
in the same run, against the target of 15 s for 1000 people.

Each world runs `dsteleop sim --trajectories N --seed 0 [--world objects] --out TMP` as a
child process (the command's own start, its 2 workers and its writing of figures included:
what a user waits for), `repeats` times in turn, after one small run per world that fills
numba's cache (a first run after an install compiles the kernels, ~15-30 s, and is reported
apart as `warmup_s`). N is 1000 (`--quick`: 100, one repeat). Per world: every run's
seconds, their median, the load average before each run, and `within_target` (the median
under 15 s; null at N other than 1000). The machine's CPU model and load are beside them
(`machine`): on a shared machine a neighbour's load lengthens every run.
"""

from __future__ import annotations

import logging
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: The study's time target [s] for 1000 people, either world (issue 32).
TARGET_S = 15.0

WORLDS: dict[str, tuple[str, ...]] = {"default": (), "objects": ("--world", "objects")}


def _sim(trajectories: int, world: tuple[str, ...], out: Path) -> float:
    """Wall seconds of one `dsteleop sim` child process; raises if it fails."""
    cmd = [sys.executable, "-m", "dsteleop.app.cli.main", "sim"]
    cmd += ["--trajectories", str(trajectories), "--seed", "0", *world, "--out", str(out)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise RuntimeError(f"bench study: {' '.join(cmd[3:])} failed: {tail}")
    return seconds


def run(quick: bool) -> dict[str, Any]:
    from dsteleop.app.bench import machine

    trajectories, repeats = (100, 1) if quick else (1000, 3)
    out: dict[str, Any] = {"trajectories": trajectories, "target_s": TARGET_S}
    with tempfile.TemporaryDirectory(prefix="dsteleop-bench-study-") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        for name, world in WORLDS.items():
            _sim(20, world, root / f"warmup-{name}")
        out["warmup_s"] = round(time.perf_counter() - t0, 2)
        runs: dict[str, list[float]] = {name: [] for name in WORLDS}
        loads: dict[str, list[list[float]]] = {name: [] for name in WORLDS}
        for i in range(repeats):  # the worlds in turn, so a neighbour's load falls on both
            for name, world in WORLDS.items():
                loads[name].append(machine()["load_average"])
                log.info("bench study: %s world, %d people, run %d", name, trajectories, i + 1)
                runs[name].append(_sim(trajectories, world, root / f"{name}-{i}"))
    for name in WORLDS:
        median = statistics.median(runs[name])
        out[name] = {
            "seconds": [round(s, 2) for s in runs[name]],
            "median_s": round(median, 2),
            "load_average_before": loads[name],
            "within_target": median < TARGET_S if trajectories == 1000 else None,
        }
    return {"study": out}
