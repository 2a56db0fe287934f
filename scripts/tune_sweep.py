"""Tune every mode compared in the sweep for each cell of the operator's world, so the sweep's
comparison uses, in each cell, parameters tuned for that cell (docs/sim.md, "The sweep").

For each cell of the design (`--design axes`, the default: the world's centre and each other
level of one axis at a time, 7 cells; `grid`: all 27), and for each mode M of `--modes`
(default DS and scalar), it runs

    dsteleop tune --objective study --mode M --metric success --trials N --trajectories T
                  --study-seed 0 --holdout-trajectories 0 --workers W
                  --goal-sigma G --delay D --depth-sigma S --out OUT/runs/<cell>/<M>

(the same budget for every mode; tuning trajectories of seed 0; the cell's world as tune's
world options, app/cli/world_options.py), then writes OUT/<cell>.json, the modes' best
parameters merged into one `--config` file (as docs/tuned/both.json: DS's fields and the
scalar baseline's `scalar.*`), and OUT/README.md with the exact commands run. A run whose
best.json is already there is kept, so a stopped script continues where it was. Held-out
judgement, on other people (seed 1):

    dsteleop sim --sweep --sweep-design axes --cell-configs OUT --seed 1 --out DIR

    .venv/bin/python scripts/tune_sweep.py --out docs/tuned/cells --trials 24 --workers 2

With `--world objects` the cells are the objects world's (the robot's perception error and
the number of objects as two more axes, app/study/sweep.py's `OBJECT_AXES`; their tune
options `--perception-depth`, `--perception-lateral` (in the world's ratio) and `--objects`)
and every tune command runs in that world.

The cells and their names come from app/study/sweep.py (`design_cells`, `cell_name`); the
tuning runs go through the `dsteleop` command in subprocesses, so this script depends only
on tune's options, not on its internals.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.jsonable import read_json
from dsteleop.app.study import planar
from dsteleop.app.study.objects import Objects
from dsteleop.app.study.sweep import (
    AXES,
    DESIGNS,
    axes_of,
    cell_name,
    centre,
    default_grid,
    design_cells,
)
from dsteleop.arbitration import ArbitrationConfig
from dsteleop.errors import DsteleopError, FormatError, InputError

#: The tune options that set a cell's world, in `AXES` order (app/cli/world_options.py).
WORLD_OPTIONS: tuple[str, ...] = ("--goal-sigma", "--delay", "--depth-sigma")
DEFAULT_MODES: tuple[str, ...] = ("DS", "scalar")


#: The worlds it tunes in: the told-goal world (`wrong-goal`) and the objects world.
WORLDS: tuple[str, ...] = ("wrong-goal", "objects")


def study(world: str = "wrong-goal") -> planar.SimConfig:
    """The study around whose world the cells lie (the objects world: its defaults, goal noise
    0, as `--world objects` sets them)."""
    if world == "objects":
        base = planar.SimConfig()
        return planar.SimConfig(objects=Objects(), world=base.world.replace(goal_sigma_m=0.0))
    return planar.SimConfig()


def cells(design: str, world: str = "wrong-goal") -> list[tuple[float, ...]]:
    """The cells of `design` over the sweep's default grid, around the world's defaults: the
    cells `dsteleop sim [--world objects] --sweep --sweep-design DESIGN` runs."""
    cfg = study(world)
    return design_cells(default_grid(cfg), design, centre(cfg))


def world_options(cell: Sequence[float], world: str = "wrong-goal") -> list[str]:
    """The tune options that set the world of `cell`."""
    out = [x for opt, v in zip(WORLD_OPTIONS, cell, strict=False) for x in (opt, f"{v:g}")]
    if world == "objects":
        o = Objects()
        depth, count = cell[len(AXES)], cell[len(AXES) + 1]
        lateral = depth * o.perception_lateral_m / o.perception_depth_m
        out = ["--world", "objects", *out, "--perception-depth", f"{depth:g}",
               "--perception-lateral", f"{lateral:g}", "--objects", f"{int(count)}"]  # fmt: skip
    return out


def tune_command(
    cell: Sequence[float],
    mode: str,
    out: Path,
    budget: Sequence[str],
    trajectories: int,
    workers: int,
    world_name: str = "wrong-goal",
) -> list[str]:
    """The `dsteleop tune` command line that tunes `mode` in the world of `cell` into `out`,
    with the budget options `budget` (the same for every mode)."""
    world = world_options(cell, world_name)
    return [
        "dsteleop", "tune", "--objective", "study", "--mode", mode, "--metric", "success",
        *budget, "--trajectories", str(trajectories), "--study-seed", "0",
        "--holdout-trajectories", "0", "--workers", str(workers), *world,
        "--out", str(out), "--no-progress", "--no-figures",
    ]  # fmt: skip


def merge_best(bests: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """One arbitration from the modes' best.json files: each mode's tuned parameters
    (`objective.params`) over the base they share (every other field).

    Args:
        bests: per mode, its `dsteleop tune` best.json (in the order of `--modes`).

    Raises:
        FormatError: a file without `arbitration` or `objective.params`.
        InputError: two modes that tuned one parameter to different values, or modes tuned
            from different bases.
    """
    tuned: dict[str, tuple[str, Any]] = {}
    for mode, best in bests.items():
        params = best.get("objective", {}).get("params")
        if not isinstance(best.get("arbitration"), dict) or not isinstance(params, dict):
            raise FormatError(f"{mode}: not a tune best.json (no arbitration or objective.params)")
        for k, v in params.items():
            if k in tuned and tuned[k][1] != v:
                raise InputError(f"{k} tuned by {tuned[k][0]} and {mode} to different values")
            tuned[k] = (mode, v)
    first, *_ = bests.values()
    base = {k: v for k, v in first["arbitration"].items() if k not in tuned}
    for mode, best in bests.items():
        other = {k: v for k, v in best["arbitration"].items() if k not in tuned}
        if other != base:
            diff = sorted(k for k in base.keys() | other.keys() if base.get(k) != other.get(k))
            raise InputError(f"{mode} was tuned from another base ({', '.join(diff)})")
    return {k: tuned[k][1] if k in tuned else v for k, v in first["arbitration"].items()}


def cell_file(
    cell: Sequence[float], bests: dict[str, dict[str, Any]], world_name: str = "wrong-goal"
) -> dict[str, Any]:
    """OUT/<cell>.json: the merged arbitration, and per mode what tune found (a `--config`
    file: `read_config_file` ignores `objective` and `note`). Where modes tuned a field they
    share to different values (DS's and DSC's kappa, p, q, b, window: fields of the one
    configuration), the arbitration is their common base with those fields at their defaults,
    and a `modes` section holds each tuned mode's own arbitration (`dsteleop sim` runs each
    mode with its own, `SimConfig.mode_arbitration`)."""
    world = dict(zip(axes_of(study(world_name)).values(), map(float, cell), strict=True))
    own: dict[str, Any] | None = None
    clash = clashing(bests)
    if clash:
        merged = merge_best({m: _untuned(b, clash) for m, b in bests.items()})  # one base
        defaults = ArbitrationConfig().to_dict()
        first, *_ = bests.values()
        arbitration = {k: defaults[k] if k in clash else merged[k] for k in first["arbitration"]}
        own = {m: dict(b["arbitration"]) for m, b in bests.items()}
    else:
        arbitration = merge_best(bests)
    out: dict[str, Any] = {
        "arbitration": arbitration,
        "objective": {
            m: {k: b["objective"].get(k) for k in ("statement", "trial", "value", "params")}
            for m, b in bests.items()
        },
        "note": f"tuned by scripts/tune_sweep.py for the sweep's cell {cell_name(cell)} "
        f"({json.dumps(world)}) on tuning trajectories of seed 0",
    }
    if own is not None:
        out["modes"] = own
    return out


def clashing(bests: dict[str, dict[str, Any]]) -> set[str]:
    """The fields two or more modes tuned to different values."""
    seen: dict[str, Any] = {}
    out: set[str] = set()
    for best in bests.values():
        for k, v in best.get("objective", {}).get("params", {}).items():
            if k in seen and seen[k] != v:
                out.add(k)
            seen.setdefault(k, v)
    return out


def _untuned(best: dict[str, Any], fields: set[str]) -> dict[str, Any]:
    """A best.json with `fields` left out of what it tuned (and out of its arbitration)."""
    params = {k: v for k, v in best["objective"]["params"].items() if k not in fields}
    arb = {k: v for k, v in best["arbitration"].items() if k not in fields}
    return {**best, "arbitration": arb, "objective": {**best["objective"], "params": params}}


def readme(commands: list[str], args: argparse.Namespace, n_cells: int, seconds: float) -> str:
    """OUT/README.md: how the files were made and how to judge them on held-out people."""
    lines = [
        "# Configurations tuned per cell of the sweep",
        "",
        f"Made by `scripts/tune_sweep.py --world {args.world} --design {args.design} "
        f"--modes {args.modes} "
        f"{_budget(args)} --trajectories {args.trajectories} --workers {args.workers} "
        + "".join(f"--reuse {r} " for r in args.reuse)
        + f"--out {args.out}` ({time.strftime('%Y-%m-%d', time.gmtime())}, {seconds:.0f} s "
        "for the runs this invocation made; a kept run's own time is in its summary.json): "
        f"{n_cells} cells, each mode of --modes tuned with the same budget on tuning "
        "trajectories of seed 0 in the cell's world"
        + "".join(f"; {r.split('=', 1)[0]} as tuned in {r.split('=', 1)[1]}" for r in args.reuse)
        + "; `<cell>.json` merges the modes' best parameters (each mode's own tuned fields over "
        "their shared defaults), `runs/<cell>/<mode>/` holds each tuning study made here.",
        "",
        "Held-out judgement (other people, seed 1):",
        "",
        "```",
        "dsteleop sim "
        + ("--world objects " if args.world == "objects" else "")
        + f"--sweep --sweep-design {args.design} --cell-configs {args.out} --seed 1 --out DIR",
        "```",
        "",
        "The commands run (a run whose best.json was already there was kept, not rerun):",
        "",
        "```",
        *commands,
        "```",
        "",
    ]
    return "\n".join(lines)


def _budget(args: argparse.Namespace) -> str:
    each = (
        f"--trials {args.trials}"
        if args.trials is not None
        else f"--trials-per-param {args.trials_per_param}"
    )
    return f"{each} --widen-edges {args.widen_edges}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, type=Path, help="folder of <cell>.json (created)")
    p.add_argument("--design", choices=DESIGNS, default="axes", help="cells (default axes)")
    p.add_argument(
        "--world", choices=WORLDS, default="wrong-goal", help="the world (default wrong-goal)"
    )
    p.add_argument("--modes", default=",".join(DEFAULT_MODES), help="tuned modes (DS,scalar)")
    each = p.add_mutually_exclusive_group()
    each.add_argument("--trials", type=int, default=None, help="tune trials per mode and cell")
    each.add_argument(
        "--trials-per-param",
        type=int,
        default=None,
        help="tune trials per searched parameter (default 4: DS 28, the scalar 8)",
    )
    p.add_argument("--widen-edges", type=int, default=2, help="tune's widening rounds (default 2)")
    p.add_argument("--trajectories", type=int, default=200, help="tuning trajectories (200)")
    p.add_argument("--workers", type=int, default=2, help="CPUs of tune's local cluster (2)")
    p.add_argument(
        "--reuse",
        action="append",
        default=[],
        metavar="MODE=DIR",
        help="merge MODE as already tuned in DIR/runs/<cell>/MODE (not rerun): e.g. "
        "DS=docs/tuned/cells with --modes scalar --trials 28, the scalar with DS's trial count",
    )
    p.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    args = p.parse_args(argv)
    modes = [m.strip() for m in str(args.modes).split(",") if m.strip()]
    if not modes or len(set(modes)) != len(modes):
        p.error(f"--modes: a list of distinct modes, got {args.modes!r}")
    reused: dict[str, Path] = {}
    for item in args.reuse:
        mode, sep, folder = item.partition("=")
        if not sep or not mode.strip() or not folder.strip():
            p.error(f"--reuse needs MODE=DIR, got {item!r}")
        if mode.strip() in modes or mode.strip() in reused:
            p.error(f"--reuse {mode.strip()}: the mode is tuned here or reused twice")
        reused[mode.strip()] = Path(folder.strip())
    for mode, folder in reused.items():
        for cell in cells(args.design, args.world):
            best = folder / "runs" / cell_name(cell) / mode / "best.json"
            if not best.is_file():
                p.error(f"--reuse {mode}: no {best}")
    if args.trials is None and args.trials_per_param is None:
        args.trials_per_param = 4
    for name in ("trials", "trials_per_param", "trajectories", "workers"):
        v = getattr(args, name)
        if v is not None and v < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {v}")
    if args.widen_edges < 0:
        p.error(f"--widen-edges must be >= 0, got {args.widen_edges}")
    budget = (
        ["--trials", str(args.trials)]
        if args.trials is not None
        else ["--trials-per-param", str(args.trials_per_param)]
    ) + ["--widen-edges", str(args.widen_edges)]
    program = Path(sys.executable).parent / "dsteleop"
    t0 = time.perf_counter()
    todo = cells(args.design, args.world)
    commands: list[str] = []
    name = ""
    try:  # a best.json unreadable, or the runs' files that do not merge: one line
        for cell in todo:
            name = cell_name(cell)
            bests: dict[str, dict[str, Any]] = {}
            for mode in modes:
                run_dir = args.out / "runs" / name / mode
                cmd = tune_command(
                    cell, mode, run_dir, budget, args.trajectories, args.workers, args.world
                )
                commands.append(shlex.join(cmd))
                sys.stdout.write(shlex.join(cmd) + "\n")
                sys.stdout.flush()
                if args.dry_run:
                    continue
                best = run_dir / "best.json"
                if not best.exists():
                    done = subprocess.run([str(program), *cmd[1:]], check=False)
                    if done.returncode != 0:
                        sys.stderr.write(f"tune_sweep: {name} {mode}: exit {done.returncode}\n")
                        return 2
                bests[mode] = read_json(best)
            for mode, folder in reused.items():
                best = folder / "runs" / name / mode / "best.json"
                bests[mode] = read_json(best)
                commands.append(f"# {mode}: reused from {best}")
            if not args.dry_run:
                args.out.mkdir(parents=True, exist_ok=True)
                data = cell_file(cell, bests, args.world)
                (args.out / f"{name}.json").write_text(json.dumps(data, indent=2) + "\n")
    except DsteleopError as e:  # `name` is the cell the loop was at
        sys.stderr.write(f"tune_sweep: {name}: {e}\n")
        return 2
    if not args.dry_run:
        text = readme(commands, args, len(todo), time.perf_counter() - t0)
        (args.out / "README.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
