"""The study's figures, shaped like the paper's Fig. 5b-5d and 6."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.study.core import SimConfig, StudyResult, heading_of, sample_trial, trace

DPI = 100
FIGURES = ("fig5b_distributions.png", "fig5c_heading.png", "fig5d_xy.png", "fig6_alpha.png")


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
    start = np.array([*cfg.start_xy_m, cfg.start_heading_rad])
    robot = {
        name: np.vstack([start, np.c_[tr.p_robot[:, :2], heading_of(tr.step.X_next.rotation)]])
        for name, tr in traces.items()
    }

    fig, ax = plt.subplots(figsize=(7, 3.6))
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.14, top=0.9)
    ax.plot(t, hand[:, 2], color=colors["operator"], label="operator")
    for name, xyh in robot.items():
        ax.plot(t, xyh[:, 2], color=colors[name], label=name)
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
        for name, xyh in robot.items():
            ax.plot(t, xyh[:, dim], color=colors[name], label=name)
        ax.set_ylabel(label)
        twin = ax.twinx()
        tt = t[1:]
        if traces:
            first = next(iter(traces.values()))
            twin.plot(
                tt, first.step.P_human[:, dim], color=colors["operator"], ls=":", label="P(H)"
            )
        for name, tr in traces.items():
            twin.plot(tt, tr.step.P_robot[:, dim], color=colors[name], ls=":", label=f"P(R) {name}")
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
            ax.plot(t[1:], tr.step.alpha[:, dim], color=colors[name], label=name)
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel(label)
    axes3[0].legend(fontsize=8)
    axes3[2].set_xlabel("time [s]")
    fig.suptitle(f"Fig. 6: alpha_i over time, S vs DS (trajectory {K})")
    fig.savefig(out / FIGURES[3], dpi=DPI)
    plt.close(fig)
    return list(FIGURES[1:])
