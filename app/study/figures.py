"""The study's figures, shaped like the paper's Fig. 5b-5d and 6."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.study.batch import example
from dsteleop.app.study.planar import SimConfig
from dsteleop.app.study.results import StudyResult

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
        title = f"{name} ({len(paths)} trajectories)"
        if name == "operator" and cfg.closed_loop:  # its hand depends on the mode
            title = f"operator's hand under {cfg.modes[0].value} ({len(paths)})"
        ax.set_title(title)
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
    runs = {m.value: example(cfg, K, m) for m in cfg.modes if m.value in ("S", "DS")}
    # The hand: one for an open-loop operator; per mode for one who watches the robot.
    hands: dict[str, tuple[Any, Any, str]]
    if cfg.closed_loop:
        hands = {f"operator ({name})": (ex.t_s, ex.hand, name) for name, ex in runs.items()}
    else:
        first = next(iter(runs.values()))
        hands = {"operator": (first.t_s, first.hand, "operator")}
    ls_hand = "--" if cfg.closed_loop else "-"
    which = "closed-loop operator" if cfg.closed_loop else f"{cfg.operator} operator"

    def plot_hands(ax: Any, dim: int) -> None:
        for label, (t, xyh, color) in hands.items():
            ax.plot(t, xyh[:, dim], color=colors[color], ls=ls_hand, lw=1.0, label=label)

    fig, ax = plt.subplots(figsize=(7, 3.6))
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.14, top=0.9)
    plot_hands(ax, 2)
    for name, ex in runs.items():
        ax.plot(ex.t_s, ex.robot[:, 2], color=colors[name], label=name)
    ax.axhline(cfg.handle_normal_rad, color="k", ls="--", lw=0.8, label="handle normal")
    tol = (
        cfg.handle_normal_rad - cfg.success_heading_rad,
        cfg.handle_normal_rad + cfg.success_heading_rad,
    )
    ax.axhspan(*tol, color="k", alpha=0.06)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("heading [rad]")
    ax.set_title(f"Fig. 5c: heading over time (trajectory {K}, {which})")
    ax.legend(fontsize=8)
    fig.savefig(out / FIGURES[1], dpi=DPI)
    plt.close(fig)

    fig, axes2 = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    fig.subplots_adjust(left=0.11, right=0.9, bottom=0.08, top=0.92, hspace=0.12)
    for row, (dim, label) in enumerate(((0, "x [m]"), (1, "y [m]"))):
        ax = axes2[row]
        plot_hands(ax, dim)
        for name, ex in runs.items():
            ax.plot(ex.t_s, ex.robot[:, dim], color=colors[name], label=name)
        ax.set_ylabel(label)
        twin = ax.twinx()
        for i, (name, ex) in enumerate(runs.items()):
            tt = ex.t_s[1:]
            if cfg.closed_loop or i == 0:  # the hand's P(H): per mode when it watches
                tag = f"P(H) {name}" if cfg.closed_loop else "P(H)"
                color = colors[name] if cfg.closed_loop else colors["operator"]
                twin.plot(
                    tt, ex.trace.step.P_human[:, dim], color=color, ls="-.", lw=0.8, label=tag
                )
            twin.plot(
                tt, ex.trace.step.P_robot[:, dim], color=colors[name], ls=":", label=f"P(R) {name}"
            )
        twin.set_ylim(0, 1.05)
        twin.set_ylabel("P")
        if row == 0:
            ax.legend(loc="upper left", fontsize=8)
            twin.legend(loc="lower right", fontsize=8)
    axes2[1].set_xlabel("time [s]")
    fig.suptitle(f"Fig. 5d: x and y over time with P(H), P(R) (trajectory {K}, {which})")
    fig.savefig(out / FIGURES[2], dpi=DPI)
    plt.close(fig)

    fig, axes3 = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.07, top=0.93, hspace=0.12)
    for row, (dim, label) in enumerate(((0, "alpha_x"), (1, "alpha_y"), (5, "alpha_heading"))):
        ax = axes3[row]
        for name, ex in runs.items():
            ax.plot(ex.t_s[1:], ex.trace.step.alpha[:, dim], color=colors[name], label=name)
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel(label)
    axes3[0].legend(fontsize=8)
    axes3[2].set_xlabel("time [s]")
    fig.suptitle(f"Fig. 6: alpha_i over time, S vs DS (trajectory {K}, {which})")
    fig.savefig(out / FIGURES[3], dpi=DPI)
    plt.close(fig)
    return list(FIGURES[1:])
