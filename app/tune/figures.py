"""The tuning study's figures.

sensitivity.png  one panel per (metric, parameter): the tuned mode's value of every
                 complete trial against the parameter (filled: the constraint held;
                 hollow: it did not; a star: the best trial), S's value as a line (a
                 horizontal line when the searched parameters do not change S, else S's
                 values joined in parameter order), one row per source and metric
heatmap.png      for a grid over two parameters: the tuned mode minus S per grid cell, one
                 panel per metric (the mean when a cell ran more than once)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.study import metric_table
from dsteleop.app.tune.driver import TrialRecord, TuneSettings
from dsteleop.app.tune.objective import key

DPI = 100
SENSITIVITY = "sensitivity.png"
HEATMAP = "heatmap.png"


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_sensitivity(
    settings: TuneSettings, recs: Sequence[TrialRecord], best: TrialRecord | None, out: Path
) -> str:
    """sensitivity.png (module docstring); returns its file name."""
    plt = _pyplot()
    done = [r for r in recs if r.state == "COMPLETE"]
    names = [m.name for m in metric_table.tuning_order()]
    rows = [(s, m) for s in settings.objective.sources for m in names]
    dims = settings.space
    tuned = settings.mode
    fig, axes = plt.subplots(
        len(rows), len(dims), figsize=(3.0 * len(dims) + 0.6, 2.3 * len(rows) + 0.8),
        squeeze=False,
    )  # fmt: skip
    for i, (source, metric) in enumerate(rows):
        ds = np.array([r.metrics.get(key(source, tuned, metric), math.nan) for r in done])
        s = np.array([r.metrics.get(key(source, "S", metric), math.nan) for r in done])
        feasible = np.array([r.feasible for r in done], dtype=bool)
        for j, d in enumerate(dims):
            ax = axes[i, j]
            x = np.array([float(r.params[d.name]) for r in done])
            if x.size:
                order = np.argsort(x, kind="stable")
                finite_s = s[np.isfinite(s)]
                if finite_s.size and np.ptp(finite_s) <= 1e-12 * max(1.0, abs(finite_s[0])):
                    ax.axhline(finite_s[0], color="tab:red", lw=1.2, label="S")
                else:
                    ax.plot(x[order], s[order], color="tab:red", lw=1.0, marker=".", ms=3,
                            label="S")  # fmt: skip
                ax.scatter(x[feasible], ds[feasible], s=16, color="tab:purple", label=tuned)
                ax.scatter(
                    x[~feasible], ds[~feasible], s=16, facecolors="none",
                    edgecolors="tab:purple", label=f"{tuned} (constraint not met)",
                )  # fmt: skip
                if best is not None:
                    ax.scatter(
                        [float(best.params[d.name])],
                        [best.metrics.get(key(source, tuned, metric), math.nan)],
                        marker="*", s=120, color="gold", edgecolors="black", zorder=5,
                        label="best",
                    )  # fmt: skip
            if d.log:
                from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

                ax.set_xscale("log")
                ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
                ax.xaxis.set_minor_formatter(NullFormatter())
            ax.axvline(float(settings.base.to_dict()[d.name]), color="gray", ls=":", lw=1)
            if i == len(rows) - 1:
                ax.set_xlabel(f"{d.name} (dotted: base)")
            if j == 0:
                ax.set_ylabel(f"{source}\n{metric_table.metric(metric).heading}")
            ax.tick_params(labelsize=7)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(
            handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.985), ncol=4,
            fontsize=8, frameon=False,
        )  # fmt: skip
    fig.suptitle(
        f"{len(done)} complete trials: each metric against each parameter", y=0.998, fontsize=10
    )
    fig.tight_layout(rect=(0, 0, 1, 1.0 - 0.5 / fig.get_size_inches()[1]))
    fig.savefig(out / SENSITIVITY, dpi=DPI)
    plt.close(fig)
    return SENSITIVITY


def write_heatmap(settings: TuneSettings, recs: Sequence[TrialRecord], out: Path) -> str | None:
    """heatmap.png for a two-parameter grid (None otherwise); returns its file name."""
    if settings.sampler != "grid" or len(settings.space) != 2:
        return None
    done = [r for r in recs if r.state == "COMPLETE"]
    if not done:
        return None
    plt = _pyplot()
    dx, dy = settings.space
    tuned = settings.mode
    xs, ys = dx.grid(settings.grid_points), dy.grid(settings.grid_points)
    names = [m.name for m in metric_table.tuning_order()]
    rows = [(s, m) for s in settings.objective.sources for m in names]
    fig, axes = plt.subplots(
        len(settings.objective.sources), len(names),
        figsize=(3.6 * len(names), 3.2 * len(settings.objective.sources) + 0.5),
        squeeze=False,
    )  # fmt: skip
    for k, (source, metric) in enumerate(rows):
        ax = axes[k // len(names), k % len(names)]
        total = np.zeros((len(ys), len(xs)))
        count = np.zeros((len(ys), len(xs)))
        for r in done:
            try:
                i, j = ys.index(r.params[dy.name]), xs.index(r.params[dx.name])
            except ValueError:
                continue
            v = r.metrics.get(key(source, tuned, metric), math.nan) - r.metrics.get(
                key(source, "S", metric), math.nan
            )
            if math.isfinite(v):
                total[i, j] += v
                count[i, j] += 1
        with np.errstate(invalid="ignore"):
            grid = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        lim = float(np.nanmax(np.abs(grid))) if np.isfinite(grid).any() else 1.0
        im = ax.imshow(grid, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
        for i in range(len(ys)):
            for j in range(len(xs)):
                if np.isfinite(grid[i, j]):
                    ax.text(j, i, f"{grid[i, j]:.2g}", ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(xs)), [f"{v:.3g}" for v in xs], fontsize=7)
        ax.set_yticks(range(len(ys)), [f"{v:.3g}" for v in ys], fontsize=7)
        ax.set_xlabel(dx.name)
        ax.set_ylabel(dy.name)
        ax.set_title(f"{source}: {metric_table.metric(metric).heading}, {tuned} - S", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    fig.savefig(out / HEATMAP, dpi=DPI)
    plt.close(fig)
    return HEATMAP
