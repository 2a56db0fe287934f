"""PNG plots of replayed runs: alpha_i, P(H), P(R), B over time; hand and robot paths."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from dsteleop.app.session.trace import Trace


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def plot_traces(traces: Sequence[Trace], out: Path) -> list[Path]:
    """One figure per run (arbitration over time) and one per session (paths); returns files."""
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
        axes[0, 0].set_title(
            f"{tr.name} - {tr.mode.value}: alpha_i, P(H), P(R), B ({tr.outcome_name})"
        )
        axes[-1, 0].set_xlabel("time [s]")
        fig.tight_layout()
        f = out / f"{_safe(tr.name)}_{_safe(tr.mode.value)}_arbitration.png"
        fig.savefig(f, dpi=80)
        plt.close(fig)
        files.append(f)

    by_session: dict[str, list[Trace]] = {}
    for tr in traces:
        by_session.setdefault(tr.name, []).append(tr)
    for name, trs in by_session.items():
        fig, ax = plt.subplots(1, 2, figsize=(10, 4.5))
        ph = trs[0].p_human
        for k, (a, b, label) in enumerate(((1, 0, "y-x (top view)"), (1, 2, "y-z (front view)"))):
            ax[k].plot(ph[:, a], ph[:, b], color="tab:green", lw=1.5, label="operator")
            for tr in trs:
                ax[k].plot(
                    tr.p_robot[:, a], tr.p_robot[:, b], lw=1.0, label=f"robot {tr.mode.value}"
                )
            ax[k].set_title(label)
            ax[k].set_aspect("equal", adjustable="datalim")
            ax[k].grid(alpha=0.3)
        ax[0].legend(fontsize=8)
        fig.suptitle(f"{name}: operator and robot trajectories (base frame, m)")
        fig.tight_layout()
        f = out / f"{_safe(name)}_trajectories.png"
        fig.savefig(f, dpi=80)
        plt.close(fig)
        files.append(f)
    return files
