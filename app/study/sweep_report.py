"""The sweep's outputs for people (`dsteleop sim --sweep`, app/study/sweep.py computes them):
sweep.md, one row per cell (in the objects world, DSC against each mode too), and sweep.png,
one panel per depth level, goal noise (rows) x delay (columns), coloured by DS minus the best
scalar mode's success (in the objects world, one panel per mode DSC is set against), from the
sweep's summary (sweep.json's object)."""

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
        more = ""
        if "objects.count" in c:
            more = (
                f", perception {c['objects.perception_depth_m']:g} m along the view, "
                f"{c['objects.count']:g} objects"
            )
        lines += [
            f"Design: {summary['design']}: the centre (goal {c['goal_sigma_m']:g} m, delay "
            f"{c['delay_s']:g} s, depth {c['depth_sigma_m']:g} m{more}) and each other level "
            "of one axis at a time.",
            "",
        ]
    configs = "cell_configs" in summary
    if configs:
        lines += [
            "Each cell ran with its own configuration (file, first 12 hex digits of its "
            "SHA-256; the parameters in cells/<cell>.json).",
            "",
        ]
    heads = {
        "goal": "goal sigma [m]", "delay": "delay [s]", "depth": "depth sigma [m]",
        "perception": "perception [m]", "objects": "objects",
    }  # fmt: skip
    axes = summary["axes"]
    lines += [
        "| "
        + " | ".join(heads[a] for a in axes)
        + " | "
        + " | ".join(modes)
        + " | best | DS - best scalar [95 % CI] | McNemar p (exact / mid) | verdict |"
        + (" configuration |" if configs else ""),
        "|"
        + " --- |" * len(axes)
        + " --- |" * len(modes)
        + " --- | --- | --- | --- |"
        + (" --- |" if configs else ""),
    ]
    for c in summary["cells"]:
        row = [f"{c['cell'][f]:g}" for f in axes.values()]
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
    if "dsc_counts" in summary:
        lines += _dsc_table(summary)
    if summary["failed"]:
        lines += ["", "Failed cells:", ""]
        lines += [f"- {k}: {v}" for k, v in summary["failed"].items()]
    lines.append("")
    return "\n".join(lines)


def _dsc_table(summary: dict[str, Any]) -> list[str]:
    """The objects world's comparison: DSC against each other mode, per cell (the success
    difference DSC minus the mode, McNemar's exact p, the verdict, the time ratio)."""
    axes = summary["axes"]
    others = list(summary["dsc_counts"])
    counts = "; ".join(
        f"{m}: " + ", ".join(f"{k} {v}" for k, v in n.items())
        for m, n in summary["dsc_counts"].items()
    )
    lines = [
        "",
        "## DSC against each mode (the objects world)",
        "",
        "Per cell: DSC's success minus the mode's (paired), McNemar's exact p, the verdict "
        f"(p < {summary['alpha']}) and DSC's time over the mode's. Counts: {counts}.",
        "",
        "| " + " | ".join(axes) + " | " + " | ".join(f"vs {m}" for m in others) + " |",
        "|" + " --- |" * (len(axes) + len(others)),
    ]
    for c in summary["cells"]:
        row = [f"{c['cell'][f]:g}" for f in axes.values()]
        for m in others:
            v = c.get("dsc_versus", {}).get(m)
            if v is None or "success_difference" not in v:
                row.append("n/a")
                continue
            row.append(
                f"{v['success_difference']:+.3f}, p {_p(v['mcnemar']['p_exact'])}, "
                f"{v['verdict']}, x{v['time_ratio']:.2f}"
            )
        lines.append("| " + " | ".join(row) + " |")
    return lines


def figure(summary: dict[str, Any], path: Path) -> None:
    """sweep.png: one panel per depth level, goal (rows) x delay (columns); colour = DS minus
    the best scalar mode's success, label = the best mode and the difference with its
    interval (* where McNemar's exact p < alpha)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if "objects" in summary["axes"]:
        return _objects_figure(summary, path, plt)
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


def _objects_figure(summary: dict[str, Any], path: Path, plt: Any) -> None:
    """The objects world's sweep.png: one panel per mode DSC is set against, perception error
    (rows) x number of objects (columns), the other axes at their first level; colour = DSC
    minus the mode's success, label = the difference (* McNemar p < alpha)."""
    grid = summary["grid"]
    axes = summary["axes"]
    perception, objects = grid["perception"], grid["objects"]
    others = list(summary.get("dsc_counts", {}))
    base = tuple(grid[a][0] for a in ("goal", "delay", "depth"))
    by = {tuple(c["cell"][f] for f in axes.values()): c for c in summary["cells"]}
    diffs = [
        abs(v["success_difference"])
        for c in summary["cells"]
        for v in c.get("dsc_versus", {}).values()
        if "success_difference" in v
    ]
    vmax = max([0.05, *diffs])
    n = max(len(others), 1)
    fig, panels = plt.subplots(
        1, n, figsize=(1.6 * len(objects) * n + 1.5, 0.9 * len(perception) + 1.6), squeeze=False
    )
    image = None
    for k, m in enumerate(others):
        ax = panels[0, k]
        val = np.full((len(perception), len(objects)), np.nan)
        for i, pe in enumerate(perception):
            for j, ob in enumerate(objects):
                c = by.get((*base, pe, ob))
                v = None if c is None else c.get("dsc_versus", {}).get(m)
                if v is None or "success_difference" not in v:
                    ax.text(j, i, "not run", ha="center", va="center", fontsize=7)
                    continue
                val[i, j] = v["success_difference"]
                star = "*" if v["mcnemar"]["p_exact"] < summary["alpha"] else ""
                colour = "white" if abs(val[i, j]) > 0.6 * vmax else "black"
                ax.text(
                    j, i, f"{val[i, j]:+.3f}{star}", ha="center", va="center", fontsize=7,
                    color=colour,
                )  # fmt: skip
        image = ax.imshow(val, cmap="RdBu", vmin=-vmax, vmax=vmax, aspect="auto")
        ax.set_xticks(range(len(objects)), [f"{o:g}" for o in objects])
        ax.set_yticks(range(len(perception)), [f"{p:g}" for p in perception])
        ax.set_xlabel("objects")
        if k == 0:
            ax.set_ylabel("perception error along the view [m]")
        ax.set_title(f"DSC - {m}", fontsize=9)
    if image is not None:
        bar = fig.colorbar(image, ax=list(panels[0]), shrink=0.9)
        bar.set_label("success: DSC minus the mode")
    fig.suptitle(
        f"The objects world: DSC against each mode ({summary['trajectories']} paired "
        f"people, * McNemar p < {summary['alpha']})",
        fontsize=9,
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _p(p: float) -> str:
    return f"{p:.3g}" if p >= 1e-300 else "< 1e-300"
