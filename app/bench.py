"""`dsteleop bench`: benchmarks that print one JSON object on stdout (logs go to stderr).

Each group is a function in its own module returning a dict of keys that are merged into the
output; `--only NAME` runs one group. Figures are medians and tail percentiles of many
repetitions, never a single timing: these machines are shared and noisy.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import sys
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import DsteleopError

# group -> "module:function"; later groups register here.
GROUPS: dict[str, str] = {
    "arbitration": "dsteleop.app.bench_arbitration:run",
    "viewer": "dsteleop.app.bench_viewer:run",
    "tracking": "dsteleop.app.bench_tracking:run",
    "robot": "dsteleop.app.bench_robot:run",
    "loop": "dsteleop.app.bench_loop:run",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--only",
        action="append",
        metavar="NAME",
        help=f"run only these groups: {', '.join(GROUPS)}",
    )
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")


def percentiles_us(samples_s: list[float] | NDArray[np.float64]) -> dict[str, float]:
    """median, p95, p99 of durations given in seconds, in microseconds."""
    a = np.asarray(samples_s, dtype=np.float64) * 1e6
    return {
        "median": round(float(np.median(a)), 2),
        "p95": round(float(np.percentile(a, 95)), 2),
        "p99": round(float(np.percentile(a, 99)), 2),
        "n": int(a.size),
    }


def machine() -> dict[str, Any]:
    return {
        "python": platform.python_version(),
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "numpy": np.__version__,
    }


def run(args: argparse.Namespace) -> int:
    names = args.only or list(GROUPS)
    unknown = [n for n in names if n not in GROUPS]
    if unknown:
        raise DsteleopError(f"unknown bench group {unknown[0]!r} (choose from {', '.join(GROUPS)})")
    out: dict[str, Any] = {"machine": machine()}
    for name in names:
        mod_name, func = GROUPS[name].split(":")
        out.update(getattr(importlib.import_module(mod_name), func)(quick=args.quick))
    json.dump(out, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0
