"""`dsteleop bench [--only GROUP[,GROUP...]] [--quick]`: benchmarks, one JSON object on stdout.

The groups are modules of app/bench/ (`GROUPS`); `--only` takes a comma-separated list of
them and may be given more than once (the groups run once each, in the order named); logs
go to stderr. `machine` in the output names the CPU model, the core count and the load
average the figures were measured under.
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
        metavar="GROUP[,GROUP...]",
        help=f"run only these groups, comma-separated (repeatable): {', '.join(GROUPS)}",
    )
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        metavar="DIR",
        help="the test-data folder with videos/ (docs/test-data.md); default $DSTELEOP_DATA",
    )


def groups(only: list[str] | None) -> list[str]:
    """The groups to run: every group without `--only`, else those named (a comma-separated
    list per `--only`, repeatable), each once, in the order named.

    Raises:
        ConfigError: an unknown group, or an `--only` that names none (one line).
    """
    if only is None:
        return list(GROUPS)
    names: list[str] = []
    for item in only:
        given = [n.strip() for n in item.split(",") if n.strip()]
        if not given:
            raise ConfigError(f"--only {item!r} names no group (choose from {', '.join(GROUPS)})")
        names += [n for n in dict.fromkeys(given) if n not in names]
    unknown = [n for n in names if n not in GROUPS]
    if unknown:
        raise ConfigError(f"unknown bench group {unknown[0]!r} (choose from {', '.join(GROUPS)})")
    return names


def run(args: argparse.Namespace) -> int:
    names = groups(args.only)
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
