"""The sweep's outputs for people (`dsteleop sim --sweep`, app/study/sweep.py computes them):
sweep.md, one row per cell, and sweep.png, one panel per depth level, goal noise (rows) x
delay (columns), coloured by DS minus the best scalar mode's success, from the sweep's summary
(sweep.json's object)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def markdown(summary: dict[str, Any]) -> str:
    """sweep.md: one row per cell."""
    modes = summary["modes"]
    lines = [
        f"# Sweep: {len(summary['cells'])} cells x {len(modes)} modes x "
        f"{summary['trajectories']} trajectories (seed {summary['seed']}, operator "
        f"`{summary['operator']}`)",
        "",
        "Every mode of a cell runs on the same trajectories (paired). Per mode: success "
        "(Laplace estimate) / geometric-mean time [s]. Best: the most successes (ties: the "
        "shorter time). DS - scalar: DS's success minus the best single-alpha mode's "
        f"({', '.join(summary['scalar_modes']) or 'none present'}), mean paired difference "
        "with its 95 % interval; McNemar's exact and mid-p tests of the paired outcomes; "
        f"verdict by the exact p < {summary['alpha']}.",
        "",
        f"Counts: {', '.join(f'{k} {v}' for k, v in summary['counts'].items())}.",
        "",
    ]
    if "design" in summary:
        c = summary["centre"]
        lines += [
            f"Design: {summary['design']}: the centre (goal {c['goal_sigma_m']:g} m, delay "
            f"{c['delay_s']:g} s, depth {c['depth_sigma_m']:g} m) and each other level of one "
            "axis at a time.",
            "",
        ]
    configs = "cell_configs" in summary
    if configs:
        lines += [
            "Each cell ran with its own configuration (file, first 12 hex digits of its "
            "SHA-256; the parameters in cells/<cell>.json).",
            "",
        ]
    lines += [
        "| goal sigma [m] | delay [s] | depth sigma [m] | "
        + " | ".join(modes)
        + " | best | DS - best scalar [95 % CI] | McNemar p (exact / mid) | verdict |"
        + (" configuration |" if configs else ""),
        "| --- | --- | --- |"
        + " --- |" * len(modes)
        + " --- | --- | --- | --- |"
        + (" --- |" if configs else ""),
    ]
    for c in summary["cells"]:
        g, d, z = (c["cell"][f] for f in summary["axes"].values())
        row = [f"{g:g}", f"{d:g}", f"{z:g}"]
        for m in modes:
            r = c["modes"].get(m)
            row.append("n/a" if r is None else f"{r['success']:.3f} / {r['time_s']:.1f}")
        row.append(str(c["best_mode"]))
        x = c.get("ds_minus_best_scalar")
        if x is None:
            row += ["n/a", "n/a", "n/a"]
        else:
            lo, hi = x["ci95"]
            row.append(f"{x['success_difference']:+.3f} [{lo:+.3f}, {hi:+.3f}] vs {x['versus']}")
            row.append(f"{_p(x['mcnemar']['p_exact'])} / {_p(x['mcnemar']['p_mid'])}")
            row.append(x["verdict"])
        if configs:
            rec = c.get("configuration") or {"file": "n/a", "sha256": ""}
            row.append(f"`{Path(rec['file']).name}` {rec['sha256'][:12]}")
        lines.append("| " + " | ".join(row) + " |")
    if summary["failed"]:
        lines += ["", "Failed cells:", ""]
        lines += [f"- {k}: {v}" for k, v in summary["failed"].items()]
    lines.append("")
    return "\n".join(lines)


def figure(summary: dict[str, Any], path: Path) -> None:
    """sweep.png: one panel per depth level, goal (rows) x delay (columns); colour = DS minus
    the best scalar mode's success, label = the best mode and the difference with its
    interval (* where McNemar's exact p < alpha)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = summary["grid"]
    goals, delays, depths = grid["goal"], grid["delay"], grid["depth"]
    by = {tuple(c["cell"][f] for f in summary["axes"].values()): c for c in summary["cells"]}
    diffs = [
        abs(c["ds_minus_best_scalar"]["success_difference"])
        for c in summary["cells"]
        if "ds_minus_best_scalar" in c
    ]
    vmax = max([0.05, *diffs])
    fig, axes = plt.subplots(
        1,
        len(depths),
        figsize=(1.9 * len(delays) * len(depths) + 1.5, 1.0 * len(goals) + 1.6),
        squeeze=False,
    )
    image = None
    for k, z in enumerate(depths):
        ax = axes[0, k]
        val = np.full((len(goals), len(delays)), np.nan)
        for i, g in enumerate(goals):
            for j, d in enumerate(delays):
                c = by.get((g, d, z))
                if c is None:
                    ax.text(j, i, "not run", ha="center", va="center", fontsize=7)
                    continue
                x = c.get("ds_minus_best_scalar")
                label = str(c["best_mode"])
                dark = False
                if x is not None:
                    val[i, j] = x["success_difference"]
                    dark = abs(val[i, j]) > 0.6 * vmax
                    lo, hi = x["ci95"]
                    star = "*" if x["mcnemar"]["p_exact"] < summary["alpha"] else ""
                    label += f"\n{x['success_difference']:+.3f}{star}\n[{lo:+.3f}, {hi:+.3f}]"
                colour = "white" if dark else "black"
                ax.text(j, i, label, ha="center", va="center", fontsize=7, color=colour)
        image = ax.imshow(val, cmap="RdBu", vmin=-vmax, vmax=vmax, aspect="auto")
        ax.set_xticks(range(len(delays)), [f"{d:g}" for d in delays])
        ax.set_yticks(range(len(goals)), [f"{g:g}" for g in goals])
        ax.set_xlabel("delay [s]")
        if k == 0:
            ax.set_ylabel("goal noise sigma [m]")
        ax.set_title(f"depth error sigma {z:g} m", fontsize=9)
    if image is not None:
        bar = fig.colorbar(image, ax=list(axes[0]), shrink=0.9)
        bar.set_label("success: DS minus best scalar")
    fig.suptitle(
        f"Where DS helps: best mode per cell; colour = DS - best scalar success "
        f"({summary['trajectories']} paired trajectories, * McNemar p < {summary['alpha']})",
        fontsize=9,
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _p(p: float) -> str:
    return f"{p:.3g}" if p >= 1e-300 else "< 1e-300"
