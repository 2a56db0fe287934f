"""Benchmarks (`dsteleop bench`, app/cli/bench.py): one module per group.

Each group is a function `run(quick) -> dict` in its own module; the dicts are merged into
one JSON object. Figures are medians and tail percentiles of many repetitions, never a single
timing: these machines are shared and noisy, so the CPU model and the load average are
reported beside them (`machine`).
"""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

# group -> "module:function"; later groups register here.
GROUPS: dict[str, str] = {
    "arbitration": "dsteleop.app.bench.arbitration:run",
    "viewer": "dsteleop.app.bench.viewer:run",
    "tracking": "dsteleop.app.bench.tracking:run",
    "robot": "dsteleop.app.bench.robot:run",
    "loop": "dsteleop.app.bench.loop:run",
    "tune": "dsteleop.app.bench.tune:run",
    "sweep": "dsteleop.app.bench.sweep:run",
    "export": "dsteleop.app.bench.export:run",
    "link": "dsteleop.app.bench.link:run",
    "inference": "dsteleop.app.bench.inference:run",
    "study": "dsteleop.app.bench.study:run",
}


def percentiles_us(samples_s: list[float] | NDArray[np.float64]) -> dict[str, float]:
    """median, p95, p99 of durations given in seconds, in microseconds."""
    a = np.asarray(samples_s, dtype=np.float64) * 1e6
    return {
        "median": round(float(np.median(a)), 2),
        "p95": round(float(np.percentile(a, 95)), 2),
        "p99": round(float(np.percentile(a, 99)), 2),
        "n": int(a.size),
    }


DATA_ENV = "DSTELEOP_DATA"


def data_dir() -> Path | None:
    """The test-data folder (docs/test-data.md), from `--data DIR` or $DSTELEOP_DATA; None
    when it is not given or does not exist."""
    text = os.environ.get(DATA_ENV)
    if not text:
        return None
    p = Path(text)
    return p if p.is_dir() else None


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict[str, Any]:
    """What the figures were measured on: CPU model, cores, load average, versions."""
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {
        "python": platform.python_version(),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "load_average": load,
        "numpy": np.__version__,
    }
