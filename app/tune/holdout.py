"""The tuned configuration against the base one on HELD-OUT data: trajectories of the
closed-loop study drawn with another seed than the tuning batch's (and, when given, held-out
sessions), so the tuned configuration is never scored on what it was tuned on. The best of
many trials on one batch is optimistic by selection; this fresh evaluation is not.

Both configurations run S and the tuned mode M (DS unless `--mode` says otherwise) on the
same held-out trajectories (paired). Reported per configuration and mode: the headline
numbers with their 95 % intervals (`app.study.summary.headline`); the gain of the tuned
configuration's M over the base's M per metric as the mean paired difference over
trajectories with its 95 % t interval (`metrics.paired_difference`; time as the ratio of
geometric means, from log times), as `gain_<M>`; and, on the tuned configuration, M against
S (the constraint, held out) with the N-1 chi-squared test, as `tuned_<M>_vs_S`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.study.metric_table import tuning_key, tuning_order
from dsteleop.app.study.results import ModeResult, StudyResult, merge
from dsteleop.app.study.summary import headline
from dsteleop.app.tasks.executor import Executor, TaskError
from dsteleop.app.tune.driver import TuneSettings
from dsteleop.app.tune.trial import (
    StudyBatch,
    paired,
    session_task,
    sessions_metrics,
    study_chunk,
)
from dsteleop.arbitration import ArbitrationConfig, metrics
from dsteleop.errors import DsteleopError

#: Trajectories per held-out task at most (smaller tasks spread better over a cluster).
CHUNK = 250


class HoldoutError(DsteleopError):
    """The held-out evaluation could not run (a task failed)."""


def study_holdout(
    executor: Executor,
    batch: StudyBatch,
    configs: Mapping[str, Mapping[str, Any]],
    on_task: Callable[[], None] | None = None,
) -> dict[str, StudyResult]:
    """Every configuration of `configs` (name -> ArbitrationConfig fields) on every
    trajectory of `batch`, S and the batch's mode, in chunks of at most CHUNK trajectories
    as tasks."""
    chunks = _chunks(batch.trajectories, executor.capacity)
    handles = {
        executor.submit(study_chunk, batch, dict(cfg), idx): name
        for name, cfg in configs.items()
        for idx in chunks
    }
    parts = _gather(executor, handles, configs, "held-out evaluation: a task failed", on_task)
    return {
        name: merge(batch.config(ArbitrationConfig.from_dict(dict(cfg))), parts[name])
        for name, cfg in configs.items()
    }


def _gather(
    executor: Executor,
    handles: Mapping[Any, str],
    names: Mapping[str, object],
    failed: str,
    on_task: Callable[[], None] | None,
) -> dict[str, list[Any]]:
    """The results of the tasks `handles` (task -> configuration name), grouped by name in
    the order they arrive; a failed task ends the evaluation (HoldoutError: `failed: why`)."""
    out: dict[str, list[Any]] = {name: [] for name in names}
    waiting = list(handles)
    while waiting:
        for h in executor.ready(waiting, timeout_s=0.5):
            waiting.remove(h)
            try:
                out[handles[h]].append(executor.result(h))
            except TaskError as exc:
                raise HoldoutError(f"{failed}: {exc}") from None
            if on_task is not None:
                on_task()
    return out


def _chunks(n: int, capacity: int) -> list[list[int]]:
    """Trajectories 0 .. n - 1 in contiguous chunks: at most CHUNK each, and at least one
    per core of the cluster."""
    pieces = max(math.ceil(n / CHUNK), min(capacity, n))
    bounds = np.linspace(0, n, pieces + 1).astype(int)
    return [list(range(a, b)) for a, b in itertools.pairwise(bounds) if b > a]


def tasks(batch: StudyBatch, configs: int, capacity: int) -> int:
    """How many tasks `study_holdout` submits."""
    return configs * len(_chunks(batch.trajectories, capacity))


def compare(
    results: Mapping[str, StudyResult],
    base: str = "base",
    tuned: str = "best",
    mode: str = "DS",
) -> dict[str, Any]:
    """The report of the module docstring from `study_holdout`'s results (`mode`: the tuned
    mode)."""
    out: dict[str, Any] = {"trajectories": int(results[base].config.trajectories)}
    for name, res in results.items():
        out[name] = {m: headline(r) for m, r in res.modes.items()}
    a, b = results[tuned].modes[mode], results[base].modes[mode]
    out[f"gain_{mode}"] = gains(a, b)
    out["gain_S"] = gains(results[tuned].modes["S"], results[base].modes["S"])
    s, ds = results[tuned].modes["S"], results[tuned].modes[mode]
    chi = metrics.n1_chi_squared(
        int(ds.success.sum()), ds.success.size, int(s.success.sum()), s.success.size
    )
    out[f"tuned_{mode}_vs_S"] = {
        f"successes_{mode}": int(ds.success.sum()),
        "successes_S": int(s.success.sum()),
        "n": int(s.success.size),
        "constraint_met": bool(ds.success.sum() >= s.success.sum()),
        "success_n1_chi2_p": chi.p_value,
        "agreement_difference": _diff(ds.agreement, s.agreement),
    }
    return out


def gains(a: ModeResult, b: ModeResult) -> dict[str, Any]:
    """Paired differences a - b per metric of the table over the same trajectories, of the
    values tuning optimises (`tuning_key`): a rate's or a linear metric's mean difference
    with its t test; a log metric's as the ratio of geometric means (`<short>_ratio`)."""
    out: dict[str, Any] = {}
    for m in tuning_order():
        k = tuning_key(m)
        x, y = a.values[k].astype(np.float64), b.values[k].astype(np.float64)
        if m.scale != "log":
            out[m.name] = _diff(x, y)
            continue
        d = metrics.paired_difference(np.log(x), np.log(y))
        out[f"{m.short or m.name}_ratio"] = {
            "mean": math.exp(d.mean),
            "ci95": [math.exp(d.ci_low), math.exp(d.ci_high)],
            "n": d.n,
        }
    return out


def _diff(a: NDArray[np.float64], b: NDArray[np.float64]) -> dict[str, Any]:
    d = metrics.paired_difference(a, b)
    t = metrics.paired_t_test(
        a[np.isfinite(a) & np.isfinite(b)], b[np.isfinite(a) & np.isfinite(b)]
    )
    return {"mean": d.mean, "ci95": [d.ci_low, d.ci_high], "n": d.n, "p_value": t.p_value}


def sessions_holdout(
    executor: Executor,
    refs: Sequence[Any],
    configs: Mapping[str, Mapping[str, Any]],
    on_task: Callable[[], None] | None = None,
    mode: str = "DS",
) -> dict[str, dict[str, float]]:
    """Every configuration on every held-out session, S and the tuned `mode`: the sessions'
    metrics per configuration (`app.tune.trial.sessions_metrics`)."""
    handles = {
        executor.submit(session_task, ref, m.value, dict(cfg)): name
        for name, cfg in configs.items()
        for ref in refs
        for m in paired(mode)
    }
    runs = _gather(executor, handles, configs, "held-out sessions: a replay failed", on_task)
    return {name: sessions_metrics(r, mode) for name, r in runs.items()}


def settings_configs(
    settings: TuneSettings, params: Mapping[str, Any]
) -> dict[str, dict[str, Any]]:
    """The two configurations compared: the base and the tuned one."""
    return {"base": settings.base.to_dict(), "best": settings.arbitration(dict(params))}
