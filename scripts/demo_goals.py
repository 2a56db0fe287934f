"""The demo person over seeds and modes, with the robot told its goal or inferring it: the
table of docs/operator.md ("The demo with inferred goals").

Each run is `dsteleop run --source demo --mode M --seed K --goal G --utensil U [--change-mind
C]` headless, one loop in a worker process (two workers by default, each run alone in its
process's loop; run it under `nice`), with U = (spoon, spatula, ladle)[K % 3] (`--utensils
cycle`, the default: the person's utensil varies with the seed, so a robot that guesses the first
candidate is not right for free) or one utensil for every seed. Per mode it prints the
successes (the person's utensil in the bin: the task counts any utensil the person grasped,
docs/operator.md, but a demo person who wanted another one did not succeed), the geometric
mean time of the successes and of all runs (a failure by timeout counts its time limit), and
with inference the belief's counts (`app.replay.belief`): the
runs whose MAP ended on the utensil grasped, the median time the MAP settled, the mean MAP
switches, and the runs whose grasped utensil was not the person's (wrong object).

    nice -n 10 .venv/bin/python scripts/demo_goals.py --goal infer --seeds 0-19 \
        --modes DS,DSC,S,scalar,conf_scalar,manual,autonomous --json /tmp/demo_infer.json

Any other option of `dsteleop run` goes after `--` (`-- --param belief.beta=2`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

UTENSILS = ("spoon", "spatula", "ladle")


def seeds_of(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def one(job: tuple[str, int, str, str, list[str]]) -> dict[str, Any]:
    """One run (module docstring), in this worker's process."""
    mode, seed, goal, utensil, extra = job
    from dsteleop.app.cli import run as run_cmd
    from dsteleop.app.compose import build
    from dsteleop.app.replay.belief import belief_metrics_of, grasped_utensil

    argv = ["run", "--source", "demo", "--mode", mode, "--seed", str(seed), "--goal", goal]
    argv += ["--utensil", utensil, *extra]
    parser = argparse.ArgumentParser(prog="dsteleop run")
    run_cmd.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    cmd = run_cmd.command(args)
    records: list[Any] = []

    class Keep:
        def observe(self, record: Any) -> None:
            records.append(record)

    built = build(cmd.options, realtime=False, observers=(Keep(),))
    loop = built.loop
    t0 = time.perf_counter()
    try:
        loop.run_headless(int(cmd.max_seconds * cmd.options.loop.rate_hz))
    finally:
        built.close()
    o = next((r.outcome for r in records if r.outcome is not None), None)
    dt = cmd.options.loop.dt_s
    return {
        "mode": mode,
        "seed": seed,
        "utensil": utensil,
        "outcome": "none" if o is None else ("success" if o.success else "failure"),
        "reason": None if o is None else o.reason,
        "grasped_utensil": grasped_utensil(records),
        "time_s": len(records) * dt if o is None else o.time_s,
        "belief": belief_metrics_of(records, dt),
        "wall_s": round(time.perf_counter() - t0, 2),
        "command": "dsteleop " + " ".join(argv),
    }


def geomean(x: list[float]) -> float | None:
    return math.exp(sum(math.log(v) for v in x) / len(x)) if x else None


def right(r: dict[str, Any]) -> bool:
    """A success of the demo: the person's utensil (the one it wanted at the end) in the bin."""
    return bool(r["outcome"] == "success" and r["grasped_utensil"] == r["final_utensil"])


def how(r: dict[str, Any]) -> str:
    """How a run that is not a success ended."""
    if r["outcome"] == "success":
        return f"the {r['grasped_utensil']} in the bin, not the {r['final_utensil']}"
    return str(r["reason"] or "none")


def table(rows: list[dict[str, Any]], modes: list[str]) -> str:
    from dsteleop.app.replay.belief import aggregate_beliefs

    lines = [
        "| mode | successes | failures (seed: how) | time of successes [s] | time of all [s] "
        "| MAP on the grasped utensil | MAP settled [s], median | MAP switches, mean "
        "| wrong utensil grasped |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for m in modes:
        rs = sorted((r for r in rows if r["mode"] == m), key=lambda r: r["seed"])
        ok = [r for r in rs if right(r)]
        bad = ", ".join(f"{r['seed']}: {how(r)}" for r in rs if r not in ok)
        gs, ga = geomean([r["time_s"] for r in ok]), geomean([r["time_s"] for r in rs])
        b = aggregate_beliefs([r["belief"] for r in rs])
        wrong = sum(1 for r in rs if r["grasped_utensil"] not in (None, r["final_utensil"]))
        if b is None:
            belief = "| - | - | - | -"
        else:
            belief = (
                f"| {b['map_right']}/{b['grasped']} | {b['map_settled_s_median']} "
                f"| {b['map_switches_mean']} | {wrong}"
            )
        lines.append(
            f"| {m} | {len(ok)}/{len(rs)} | {bad or '-'} | "
            f"{'-' if gs is None else f'{gs:.1f}'} | {'-' if ga is None else f'{ga:.1f}'} "
            f"{belief} |"
        )
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--modes", default="DS,DSC,S,scalar,conf_scalar,manual,autonomous")
    p.add_argument("--seeds", default="0-19")
    p.add_argument("--goal", default="infer", help="infer, or told (the person's utensil)")
    p.add_argument("--utensils", default="cycle", help="cycle, or one utensil for every seed")
    p.add_argument("--change-mind", default=None, metavar="UTENSIL:S|next:S")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json", default=None, help="write every run here")
    p.add_argument("extra", nargs="*", help="more `dsteleop run` options, after --")
    a = p.parse_args()
    modes = a.modes.split(",")
    jobs = []
    for seed in seeds_of(a.seeds):
        utensil = UTENSILS[seed % 3] if a.utensils == "cycle" else a.utensils
        goal = utensil if a.goal == "told" else a.goal
        extra = list(a.extra)
        final = utensil
        if a.change_mind:
            to, _, at = a.change_mind.partition(":")
            if to == "next":  # the next utensil along the holder, whichever the person's
                to = UTENSILS[(UTENSILS.index(utensil) + 1) % 3]
            extra += ["--change-mind", f"{to}:{at}"]
            final = to
        for m in modes:
            jobs.append(((m, seed, goal, utensil, extra), final))
    t0 = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(a.workers) as pool:
        for i, r in enumerate(pool.map(one, [j for j, _ in jobs])):
            rows.append(r)
            sys.stderr.write(  # progress: a long table on a shared machine
                f"{i + 1}/{len(jobs)} {r['mode']} seed {r['seed']}: {r['outcome']} "
                f"{r['grasped_utensil']} {r['time_s']:.1f} s sim, {r['wall_s']} s wall\n"
            )
            sys.stderr.flush()
    for r, (_, final) in zip(rows, jobs, strict=True):
        r["final_utensil"] = final
    sys.stdout.write(table(rows, modes) + "\n")
    load = os.getloadavg()[0]
    sys.stderr.write(f"{len(rows)} runs, {time.perf_counter() - t0:.0f} s wall, load {load:.1f}\n")
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
