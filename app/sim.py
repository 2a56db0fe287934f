"""`dsteleop sim`: the paper's simulation study (Section IV-A/B), S vs DS on planar trajectories.

    dsteleop sim --trajectories 1000 --seed 0 --out DIR [--workers N] [--operator side|aligned]

writes DIR/summary.json, DIR/summary.md (shaped like the paper's Table I) and PNG figures
shaped like Fig. 5b-5d and 6 (`--example K` picks the trajectory of 5c, 5d and 6), and prints
one JSON object on stdout. The computation lives in `dsteleop.app.sim_core` (pure); this
module is the edge: arguments, processes, progress bar, files and figures. docs/sim.md
describes the study and the operator model.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app import sim_core
from dsteleop.app.cli_util import Progress, prepare_out_dir
from dsteleop.app.sim_core import (
    ChunkResult,
    SimConfig,
    StudyResult,
    heading_of,
    merge,
    run_chunk,
    sample_trial,
    trace,
)
from dsteleop.arbitration import ArbitrationConfig, InvalidConfig, Mode
from dsteleop.errors import DsteleopError

log = logging.getLogger("dsteleop.sim")

DPI = 100
FIGURES = ("fig5b_distributions.png", "fig5c_heading.png", "fig5d_xy.png", "fig6_alpha.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trajectories",
        type=int,
        default=1000,
        metavar="N",
        help="number of operator trajectories (default 1000)",
    )
    parser.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    parser.add_argument(
        "--out", required=True, metavar="DIR", help="output directory (created if missing)"
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=0,
        metavar="N",
        help="processes (default 0: one per core, at most 4)",
    )
    parser.add_argument(
        "--operator",
        default="side",
        help=(
            "side (the paper's scenario: agrees on position, prefers another heading) "
            "or aligned (agrees on every dimension)"
        ),
    )
    parser.add_argument(
        "--modes",
        default="S,DS,manual,autonomous",
        help="comma-separated arbitration modes (default all four)",
    )
    parser.add_argument(
        "--example",
        type=int,
        default=None,
        metavar="K",
        help="trajectory drawn in Fig. 5c, 5d and 6 (default: the first that moves y before x)",
    )
    parser.add_argument(
        "--goal-sigma",
        type=float,
        default=None,
        metavar="M",
        help="robot goal position noise per axis [m] (default 0.02)",
    )
    parser.add_argument(
        "--success-radius",
        type=float,
        default=None,
        metavar="M",
        help="success radius R [m] (default 0.03)",
    )
    parser.add_argument(
        "--success-heading",
        type=float,
        default=None,
        metavar="RAD",
        help="success heading tolerance delta [rad] (default 0.35)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="arbitration hyper-parameter, e.g. kappa=6 (repeatable)",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    bar = parser.add_mutually_exclusive_group()
    bar.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="always draw the progress bar",
    )
    bar.add_argument(
        "--no-progress", dest="progress", action="store_false", help="never draw the progress bar"
    )


def run(args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    cfg = config_from_args(args)
    workers = _workers(args.workers, cfg.trajectories)
    out = prepare_out_dir(Path(args.out))
    modes = ",".join(m.value for m in cfg.modes)
    log.info(
        "sim: %d trajectories, operator %s, modes %s, %d worker(s), out %s",
        *(cfg.trajectories, cfg.operator, modes, workers, out),
    )
    show = sys.stderr.isatty() if args.progress is None else bool(args.progress)
    files = ["summary.json", "summary.md"]
    example = cfg.example if cfg.example is not None else sim_core.first_lead_index(cfg)

    def example_figures() -> None:
        # Needs only the configuration: drawn while the workers simulate.
        files.extend(write_example_figures(cfg, example, out))

    with Progress(
        cfg.trajectories * len(cfg.modes), sys.stderr, show, "sim", "trajectory-modes"
    ) as bar:
        result = simulate(cfg, workers, bar, None if args.no_figures else example_figures)
    summary = sim_core.summarise(result)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    (out / "summary.md").write_text(markdown(summary))
    if not args.no_figures:
        files.insert(2, write_distribution_figure(result, out))
    printed = brief(summary, out, files, time.monotonic() - t0, workers)
    printed["example"] = None if args.no_figures else example
    json.dump(printed, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


def config_from_args(args: argparse.Namespace) -> SimConfig:
    """The SimConfig of the command line; bad values raise DsteleopError."""
    modes: list[Mode] = []
    for name in (s.strip() for s in str(args.modes).split(",")):
        try:
            modes.append(Mode.parse(name))
        except ValueError as exc:
            raise DsteleopError(str(exc)) from None
    arb = ArbitrationConfig()
    changes: dict[str, Any] = {}
    for item in args.param:
        name, sep, value = item.partition("=")
        if not sep:
            raise DsteleopError(f"--param needs NAME=VALUE, got {item!r}")
        try:
            changes[name.strip()] = int(value) if name.strip() == "window" else float(value)
        except ValueError:
            raise DsteleopError(f"--param {name}: not a number: {value!r}") from None
    try:
        arb = ArbitrationConfig.from_dict({**arb.to_dict(), **changes})
    except (InvalidConfig, TypeError) as exc:
        raise DsteleopError(str(exc)) from None
    if args.operator not in ("side", "aligned"):
        raise DsteleopError(f"unknown operator {args.operator!r} (choose from side, aligned)")
    extra: dict[str, Any] = {}
    for arg, name in (
        ("goal_sigma", "goal_sigma_m"),
        ("success_radius", "success_radius_m"),
        ("success_heading", "success_heading_rad"),
    ):
        v = getattr(args, arg)
        if v is not None:
            extra[name] = float(v)
    if args.trajectories < 1:
        raise DsteleopError(f"--trajectories must be >= 1, got {args.trajectories}")
    return SimConfig(
        trajectories=args.trajectories,
        seed=args.seed,
        operator=args.operator,
        modes=tuple(modes),
        example=args.example,
        arbitration=arb,
        **extra,
    )


def _workers(requested: int, trajectories: int) -> int:
    if requested < 0:
        raise DsteleopError(f"--workers must be >= 0 (0: automatic), got {requested}")
    if requested == 0:
        requested = min(os.cpu_count() or 1, 4)
    # Fewer than ~100 trajectories per process is not worth a process.
    return max(1, min(requested, math.ceil(trajectories / 100)))


# --- running over processes -----------------------------------------------------------------

_QUEUE: Any = None


def _init_worker(queue: Any) -> None:
    global _QUEUE  # noqa: PLW0603 - one queue per worker process, set once by the pool
    _QUEUE = queue


def _work(job: tuple[SimConfig, list[int]]) -> ChunkResult:
    cfg, indices = job
    return run_chunk(cfg, indices, on_progress=_QUEUE.put if _QUEUE is not None else None)


def simulate(
    cfg: SimConfig,
    workers: int,
    bar: Progress | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> StudyResult:
    """Run every trajectory under every mode; chunks over `workers` processes.

    Each trajectory is seeded by (seed, index) and the arbitration works row by row, so the
    numbers do not depend on `workers` (beyond the last bits). `meanwhile` runs in this
    process while the workers compute (after the run with one worker).
    """
    n = cfg.trajectories
    if workers <= 1:
        chunks = [run_chunk(cfg, list(range(n)), on_progress=bar.advance if bar else None)]
        if meanwhile is not None:
            meanwhile()
        return merge(cfg, chunks)
    n_chunks = workers  # one chunk each: bigger batches step more efficiently
    bounds = np.linspace(0, n, n_chunks + 1).astype(int)
    jobs = [(cfg, list(range(a, b))) for a, b in itertools.pairwise(bounds) if b > a]
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    queue = ctx.SimpleQueue()
    with ctx.Pool(workers, initializer=_init_worker, initargs=(queue,)) as pool:
        pending = pool.map_async(_work, jobs)
        if meanwhile is not None:
            meanwhile()
        while not pending.ready():
            pending.wait(0.1)
            while not queue.empty():
                done = queue.get()
                if bar:
                    bar.advance(done)
        chunks = pending.get()
        while not queue.empty():
            done = queue.get()
            if bar:
                bar.advance(done)
    return merge(cfg, chunks)


# --- outputs --------------------------------------------------------------------------------


def brief(
    summary: dict[str, Any], out: Path, files: Sequence[str], elapsed_s: float, workers: int
) -> dict[str, Any]:
    """The JSON object printed on stdout: where the files are and the headline numbers."""
    modes = {
        name: {
            "success_rate": m["success_rate"]["estimate"],
            "time_s": m["time_s"]["geometric_mean"],
            "cosine_distance": m["cosine_distance"]["mean"],
            "agreement": m["agreement"]["mean"],
        }
        for name, m in summary["modes"].items()
    }
    tests = summary["tests"].get("S_vs_DS")
    p = None
    if tests:
        p = {
            "success": tests["success_n1_chi2"]["p_value"],
            "log_time": tests["log_time"]["two_sample_t"]["p_value"],
            "cosine_distance": tests["cosine_distance"]["two_sample_t"]["p_value"],
            "agreement": tests["agreement"]["two_sample_t"]["p_value"],
        }
    return {
        "out": str(out),
        "files": list(files),
        "operator": summary["operator"]["kind"],
        "trajectories": summary["trajectories"],
        "seed": summary["seed"],
        "modes": modes,
        "p_S_vs_DS": p,
        "workers": workers,
        "elapsed_s": round(elapsed_s, 3),
    }


def markdown(summary: dict[str, Any]) -> str:
    """summary.md: the paper's Table I shape, then the tests and divergences."""
    tests = summary["tests"].get("S_vs_DS")
    # Bold marks the better of S and DS where the difference is significant (p < 0.05), as
    # in the paper's Table I.
    better: dict[str, str | None] = {}
    if tests:

        def pick(key: str, p: float, s_val: float, ds_val: float, lower: bool) -> None:
            if p < 0.05:
                better[key] = (
                    ("S" if s_val < ds_val else "DS")
                    if lower
                    else ("S" if s_val > ds_val else "DS")
                )

        m = summary["modes"]
        for key, test, metric, stat, lower in (
            ("success", tests["success_n1_chi2"], "success_rate", "estimate", False),
            ("time", tests["log_time"]["two_sample_t"], "time_s", "geometric_mean", True),
            ("cos", tests["cosine_distance"]["two_sample_t"], "cosine_distance", "mean", True),
            ("agree", tests["agreement"]["two_sample_t"], "agreement", "mean", False),
        ):
            pick(key, test["p_value"], m["S"][metric][stat], m["DS"][metric][stat], lower)

    def cell(
        key: str, mode: str, est: float | None, ci: Sequence[float | None], digits: int
    ) -> str:
        if est is None:
            return "n/a"
        lo, hi = ci
        text = f"{est:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
        return f"**{text}**" if better.get(key) == mode else text

    lines = [
        f"# Simulation study: {summary['trajectories']} trajectories, seed {summary['seed']}, "
        f"operator `{summary['operator']['kind']}`",
        "",
        "Means and 95 % confidence intervals (success: Laplace estimate, adjusted-Wald; time: "
        "geometric mean; cosine distance and agreement: mean of the per-trajectory values, t "
        "interval). Bold: better of S and DS with p < 0.05.",
        "",
        "| Mode | Success Rate | Trial Time (s) | Cosine Distance | Ratio of Agreement |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, m in summary["modes"].items():
        lines.append(
            f"| {name} | "
            + " | ".join(
                [
                    cell(
                        "success", name, m["success_rate"]["estimate"], m["success_rate"]["ci95"], 3
                    ),
                    cell("time", name, m["time_s"]["geometric_mean"], m["time_s"]["ci95"], 2),
                    cell(
                        "cos", name, m["cosine_distance"]["mean"], m["cosine_distance"]["ci95"], 3
                    ),
                    cell("agree", name, m["agreement"]["mean"], m["agreement"]["ci95"], 3),
                ]
            )
            + " |"
        )
    if tests:
        lines += [
            "",
            "## S vs DS (same trajectories)",
            "",
            "| Metric | Test | Statistic | p |",
            "| --- | --- | --- | --- |",
            "| success | N-1 chi-squared | "
            f"{tests['success_n1_chi2']['chi2']:.3f} | {_p(tests['success_n1_chi2']['p_value'])} |",
        ]
        for key, label in (
            ("log_time", "log time"),
            ("cosine_distance", "cosine distance"),
            ("agreement", "agreement"),
        ):
            for test, tlabel in (("two_sample_t", "two-sample t"), ("paired_t", "paired t")):
                r = tests[key][test]
                lines.append(f"| {label} | {tlabel} | {r['t']:.3f} | {_p(r['p_value'])} |")
    lines += ["", "## Cosine distance and agreement by phase of the trial (deciles)", ""]
    edges = next(iter(summary["modes"].values()))["by_phase"]["edges"]
    head = " | ".join(f"{a:.1f}-{b:.1f}" for a, b in itertools.pairwise(edges))
    lines += [f"| Mode | Metric | {head} |", "| --- | --- |" + " --- |" * (len(edges) - 1)]
    for name, m in summary["modes"].items():
        for key, label in (("cosine_distance", "cosine"), ("agreement", "agreement")):
            vals = " | ".join("n/a" if v is None else f"{v:.3f}" for v in m["by_phase"][key])
            lines.append(f"| {name} | {label} | {vals} |")
    lines += ["", "## Jensen-Shannon divergence of (x, y, heading) histograms (base 2)", ""]
    lines += ["| Pair | JSD |", "| --- | --- |"]
    lines += [f"| {k} | {v:.4f} |" for k, v in summary["divergence"].items()]
    c = summary["config"]
    lines += [
        "",
        "## Configuration",
        "",
        f"- handle at {c['handle_xy_m']} m, normal {c['handle_normal_rad']:.4f} rad; success R = "
        f"{c['success_radius_m']} m, delta = {c['success_heading_rad']} rad",
        f"- robot goal noise sigma = {c['goal_sigma_m']} m; dt = {c['dt_s']:.5f} s",
        f"- arbitration: {json.dumps(c['arbitration'], sort_keys=True)}",
        "",
    ]
    return "\n".join(lines)


def _p(p: float) -> str:
    return f"{p:.3g}" if p >= 1e-300 else "< 1e-300"


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


COLORS = {
    "operator": "tab:green",
    "S": "tab:red",
    "DS": "tab:purple",
    "manual": "tab:gray",
    "autonomous": "tab:blue",
}


def write_distribution_figure(result: StudyResult, out: Path) -> str:
    """Fig. 5b: x-y paths of the operator, S and DS; returns the file name."""
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    cfg, colors = result.config, COLORS
    hx, hy = cfg.handle_xy_m
    sx, sy = cfg.start_xy_m

    # Fig. 5b: trajectory distributions of the operator, S and DS.
    panels = [("operator", result.operator_paths)] + [
        (m, result.modes[m].paths) for m in ("S", "DS") if m in result.modes
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.4), squeeze=False)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.12, top=0.85, wspace=0.3)
    for ax, (name, paths) in zip(axes[0], panels):
        segs = [p[np.isfinite(p[:, 0]), :2] for p in paths]
        ax.add_collection(LineCollection(segs, colors=colors[name], alpha=0.15, linewidths=0.8))
        ax.autoscale_view()
        ax.plot([sx], [sy], "ks", ms=7, label="start")
        ax.plot([hx], [hy], marker="*", color="k", ms=12, ls="", label="handle")
        ax.set_title(f"{name} ({len(paths)} trajectories)")
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
    axes[0][0].set_ylabel("y [m]")
    axes[0][0].legend(loc="lower right", fontsize=8)
    fig.suptitle("Fig. 5b: trajectory distributions")
    fig.savefig(out / FIGURES[0], dpi=DPI)
    plt.close(fig)
    return FIGURES[0]


def write_example_figures(cfg: SimConfig, K: int, out: Path) -> list[str]:
    """Fig. 5c (heading), 5d (x, y with P(H), P(R)) and 6 (alpha_i) of trajectory K."""
    plt = _pyplot()
    colors = COLORS
    trial = sample_trial(cfg, K)
    t = trial.t_s
    hand = np.concatenate(
        [trial.hand.position[:, :2], heading_of(trial.hand.rotation)[:, None]], -1
    )
    traces = {m.value: trace(cfg, K, m) for m in cfg.modes if m.value in ("S", "DS")}

    fig, ax = plt.subplots(figsize=(7, 3.6))
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.14, top=0.9)
    ax.plot(t, hand[:, 2], color=colors["operator"], label="operator")
    for name, tr in traces.items():
        ax.plot(t, tr.robot[:, 2], color=colors[name], label=name)
    ax.axhline(cfg.handle_normal_rad, color="k", ls="--", lw=0.8, label="handle normal")
    tol = (
        cfg.handle_normal_rad - cfg.success_heading_rad,
        cfg.handle_normal_rad + cfg.success_heading_rad,
    )
    ax.axhspan(*tol, color="k", alpha=0.06)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("heading [rad]")
    ax.set_title(f"Fig. 5c: heading over time (trajectory {K})")
    ax.legend(fontsize=8)
    fig.savefig(out / FIGURES[1], dpi=DPI)
    plt.close(fig)

    fig, axes2 = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    fig.subplots_adjust(left=0.11, right=0.9, bottom=0.08, top=0.92, hspace=0.12)
    for row, (dim, label) in enumerate(((0, "x [m]"), (1, "y [m]"))):
        ax = axes2[row]
        ax.plot(t, hand[:, dim], color=colors["operator"], label="operator")
        for name, tr in traces.items():
            ax.plot(t, tr.robot[:, dim], color=colors[name], label=name)
        ax.set_ylabel(label)
        twin = ax.twinx()
        tt = t[1:]
        if traces:
            first = next(iter(traces.values()))
            twin.plot(tt, first.P_human[:, dim], color=colors["operator"], ls=":", label="P(H)")
        for name, tr in traces.items():
            twin.plot(tt, tr.P_robot[:, dim], color=colors[name], ls=":", label=f"P(R) {name}")
        twin.set_ylim(0, 1.05)
        twin.set_ylabel("P")
        if row == 0:
            ax.legend(loc="upper left", fontsize=8)
            twin.legend(loc="lower right", fontsize=8)
    axes2[1].set_xlabel("time [s]")
    fig.suptitle(f"Fig. 5d: x and y over time with P(H), P(R) (trajectory {K})")
    fig.savefig(out / FIGURES[2], dpi=DPI)
    plt.close(fig)

    fig, axes3 = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.07, top=0.93, hspace=0.12)
    for row, (dim, label) in enumerate(((0, "alpha_x"), (1, "alpha_y"), (5, "alpha_heading"))):
        ax = axes3[row]
        for name, tr in traces.items():
            ax.plot(t[1:], tr.alpha[:, dim], color=colors[name], label=name)
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel(label)
    axes3[0].legend(fontsize=8)
    axes3[2].set_xlabel("time [s]")
    fig.suptitle(f"Fig. 6: alpha_i over time, S vs DS (trajectory {K})")
    fig.savefig(out / FIGURES[3], dpi=DPI)
    plt.close(fig)
    return list(FIGURES[1:])
