"""PNG plots of replayed runs: alpha_i, P(H), P(R), B over time; per episode, the hand's and
the robot's paths in metres with the goals, and their positions over time with the task's
phases; for a robot that infers its goal, its belief over the candidates and its confidence
over time (`belief_figure`)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from dsteleop.robot.task import Phase

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from dsteleop.app.session.trace import Trace

Array = NDArray[np.float64]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


PHASE_SHADES = {Phase.PICK: "#dbe9f6", Phase.PLACE: "#fde2c8", Phase.DONE: "#e0e0e0"}
AXES = ("x", "y", "z")


def _goals(tr: Trace) -> list[tuple[str, Array]]:
    """The goals the robot knew in the run, in order: ("pick goal", p), ("place goal", p).

    A tick's goal is the one it started with and its phase the one after it, so the tick
    that grasps is the first of the place phase yet still holds the pick goal: a phase's goal
    is read from the ticks that started in it (the phase of the tick before)."""
    out: list[tuple[str, Array]] = []
    started_in = (Phase.PICK, *tr.phases[:-1])
    for phase in (Phase.PICK, Phase.PLACE):
        rows = [
            k for k, ph in enumerate(started_in) if ph is phase and np.isfinite(tr.p_goal[k, 0])
        ]
        if rows:
            out.append((f"{phase.value} goal", tr.p_goal[rows[0]]))
    return out


def _phase_spans(tr: Trace) -> list[tuple[Phase, float, float]]:
    """(phase, start [s], end [s]) of each stretch of one phase."""
    spans: list[tuple[Phase, float, float]] = []
    t = tr.t_s
    for k, ph in enumerate(tr.phases):
        end = float(t[k + 1]) if k + 1 < len(t) else float(t[k])
        if spans and spans[-1][0] is ph:
            spans[-1] = (ph, spans[-1][1], end)
        else:
            spans.append((ph, float(t[k]), end))
    return spans


#: The title suffix of an open-loop replay's figures (`replay.core.LOOP_NOTES`).
OPEN_LOOP = "open loop: recorded hand replayed"


def trajectory_figure(name: str, traces: Sequence[Trace], open_loop: bool = False) -> Figure:
    """The paths of one episode, in the robot base frame with axes in metres: the operator's
    mapped hand and the robot's palm in each mode, from above (y-x) and from the front
    (y-z), with the goals the robot knew; and x, y, z over time with the task's phases
    shaded (pick, place, done) and the goals as dashed lines; `open_loop`: the title says
    the runs are open loop (a recorded hand replayed)."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    fig = plt.figure(figsize=(12, 8))
    grid = fig.add_gridspec(2, 2, height_ratios=(1.2, 1.0))
    views = (fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]))
    ph = traces[0].p_human
    goals = _goals(traces[0])
    for ax, (a, b, title) in zip(views, ((1, 0, "from above"), (1, 2, "from the front"))):
        ax.plot(ph[:, a], ph[:, b], color="tab:blue", lw=1.5, label="operator (mapped hand)")
        for tr in traces:
            ax.plot(tr.p_robot[:, a], tr.p_robot[:, b], lw=1.0, label=f"robot, {tr.mode.value}")
        for (label, p), marker in zip(goals, ("o", "s")):
            ax.plot(p[a], p[b], marker, ms=9, mfc="none", mew=2, color="black", label=label)
        ax.set_xlabel(f"{AXES[a]} [m] (base frame, y left)")
        ax.set_ylabel(f"{AXES[b]} [m]")
        ax.set_title(f"{title} ({AXES[a]}-{AXES[b]})")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    views[0].legend(fontsize=8, loc="best")
    over_time = fig.add_subplot(grid[1, :])
    first = traces[0]
    for phase, t0, t1 in _phase_spans(first):
        over_time.axvspan(t0, t1, color=PHASE_SHADES[phase], lw=0)
    colours = ("tab:red", "tab:green", "tab:purple")
    for i, c in enumerate(colours):
        over_time.plot(first.t_s, first.p_robot[:, i], color=c, lw=1.2, label=f"robot {AXES[i]}")
        over_time.plot(first.t_s, ph[:, i], color=c, lw=0.8, ls=":", label=f"operator {AXES[i]}")
        for _, p in goals:
            over_time.axhline(p[i], color=c, lw=0.7, ls="--")
    handles, labels = over_time.get_legend_handles_labels()
    names = [f"phase {p.value}" for p in PHASE_SHADES]
    phases = [Patch(color=PHASE_SHADES[p], label=n) for p, n in zip(PHASE_SHADES, names)]
    over_time.legend([*handles, *phases], [*labels, *names], fontsize=7, ncol=5)
    over_time.set_xlabel("time [s]")
    over_time.set_ylabel("position [m] (dashed: goals)")
    over_time.set_title(f"{first.mode.value} run: position over time, phases shaded")
    over_time.grid(alpha=0.3)
    loop = f" ({OPEN_LOOP})" if open_loop else ""
    fig.suptitle(f"{name}: operator and robot paths, robot base frame [m]{loop}")
    fig.tight_layout()
    return fig


def belief_figure(tr: Trace, open_loop: bool = False) -> Figure | None:
    """A robot that infers its goal: its belief in each candidate over time (the bin's from
    the place phase on), the utensil grasped named, and below it the confidence per
    dimension of the goal it sought, with the joint one; None for a run without a belief."""
    if not any(b is not None for b in tr.beliefs):
        return None
    import matplotlib.pyplot as plt

    names: list[str] = []
    for b in tr.beliefs:
        for n in b.names if b is not None else ():
            if n not in names:
                names.append(n)
    T = len(tr)
    p = np.full((T, len(names)), np.nan)
    c = np.full((T, len(tr.dims) + 1), np.nan)
    for k, b in enumerate(tr.beliefs):
        if b is not None:
            p[k, [names.index(n) for n in b.names]] = b.probability
            c[k] = [*b.confidence, b.confidence_joint]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    for phase, t0, t1 in _phase_spans(tr):
        for ax in (top, bottom):
            ax.axvspan(t0, t1, color=PHASE_SHADES[phase], lw=0)
    for j, n in enumerate(names):
        bold = n == tr.grasped
        top.plot(tr.t_s, p[:, j], lw=2.0 if bold else 1.2, label=n + (" (grasped)" if bold else ""))
    top.set_ylim(-0.02, 1.02)
    top.set_ylabel("belief")
    top.legend(fontsize=8, loc="center right")
    top.grid(alpha=0.3)
    for i, d in enumerate(tr.dims):
        bottom.plot(tr.t_s, c[:, i], lw=0.9, label=d)
    bottom.plot(tr.t_s, c[:, -1], color="black", lw=2.0, label="joint")
    bottom.set_ylim(-0.02, 1.02)
    bottom.set_ylabel("confidence c")
    bottom.set_xlabel("time [s] (phases shaded: pick, place, done)")
    bottom.legend(fontsize=7, ncol=6, loc="lower right")
    bottom.grid(alpha=0.3)
    loop = f"; {OPEN_LOOP}" if open_loop else ""
    top.set_title(
        f"{tr.name} - {tr.mode.value}: the robot's belief over its goal and its confidence "
        f"({tr.outcome_name}{loop})"
    )
    fig.tight_layout()
    return fig


def plot_traces(traces: Sequence[Trace], out: Path, open_loop: bool = False) -> list[Path]:
    """One figure per run (arbitration over time) and one per episode (`trajectory_figure`);
    returns the files. `open_loop`: every title says the runs are open loop."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files: list[Path] = []
    for tr in traces:
        D = len(tr.dims)
        fig, axes = plt.subplots(D, 1, figsize=(8, 1.3 * D + 1), sharex=True, squeeze=False)
        for i, ax in enumerate(axes[:, 0]):
            m = tr.arbitrated
            t = tr.t_s
            for arr, label, color in (
                (tr.step.alpha, "alpha", "black"),
                (tr.step.P_human, "P(H)", "tab:green"),
                (tr.step.P_robot, "P(R)", "tab:red"),
                (tr.step.B, "B", "tab:purple"),
            ):
                y = np.where(m, arr[:, i], np.nan)
                ax.plot(t, y, label=label, color=color, lw=1.4 if label == "alpha" else 0.9)
            ax.set_ylim(-0.05, 1.05)
            ax.set_ylabel(tr.dims[i], rotation=0, ha="right", va="center")
            ax.grid(alpha=0.3)
        axes[0, 0].legend(ncol=4, fontsize=8, loc="upper right")
        loop = f"; {OPEN_LOOP}" if open_loop else ""
        axes[0, 0].set_title(
            f"{tr.name} - {tr.mode.value}: alpha_i, P(H), P(R), B ({tr.outcome_name}{loop})"
        )
        axes[-1, 0].set_xlabel("time [s]")
        fig.tight_layout()
        f = out / f"{_safe(tr.name)}_{_safe(tr.mode.value)}_arbitration.png"
        fig.savefig(f, dpi=80)
        plt.close(fig)
        files.append(f)

        belief = belief_figure(tr, open_loop)
        if belief is not None:
            f = out / f"{_safe(tr.name)}_{_safe(tr.mode.value)}_belief.png"
            belief.savefig(f, dpi=80)
            plt.close(belief)
            files.append(f)

    by_episode: dict[str, list[Trace]] = {}
    for tr in traces:
        by_episode.setdefault(tr.name, []).append(tr)
    for name, trs in by_episode.items():
        fig = trajectory_figure(name, trs, open_loop)
        f = out / f"{_safe(name)}_trajectories.png"
        fig.savefig(f, dpi=80)
        plt.close(fig)
        files.append(f)
    return files
