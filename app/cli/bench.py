"""`dsteleop bench [--only GROUP] [--quick]`: benchmarks, one JSON object on stdout.

The groups are modules of app/bench/ (`GROUPS`); logs go to stderr. `machine` in the output
names the CPU model, the core count and the load average the figures were measured under.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from pathlib import Path
from typing import Any

from dsteleop.app.bench import DATA_ENV, GROUPS, data_dir, machine
from dsteleop.errors import ConfigError, InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--only",
        action="append",
        metavar="NAME",
        help=f"run only these groups: {', '.join(GROUPS)}",
    )
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        metavar="DIR",
        help="the test-data folder with videos/ (docs/test-data.md); default $DSTELEOP_DATA",
    )


def run(args: argparse.Namespace) -> int:
    names = args.only or list(GROUPS)
    unknown = [n for n in names if n not in GROUPS]
    if unknown:
        raise ConfigError(f"unknown bench group {unknown[0]!r} (choose from {', '.join(GROUPS)})")
    if args.data is not None:
        if not (args.data / "videos").is_dir():
            raise InputError(f"--data {args.data}: no videos/ folder there")
        os.environ[DATA_ENV] = str(args.data)
    out: dict[str, Any] = {
        "machine": machine(),
        "data": None if data_dir() is None else str(data_dir()),
    }
    for name in names:
        mod_name, func = GROUPS[name].split(":")
        out.update(getattr(importlib.import_module(mod_name), func)(quick=args.quick))
    out["machine_after"] = {"load_average": machine()["load_average"]}
    json.dump(out, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0
