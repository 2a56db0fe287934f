"""The study's summary over trajectories and its statistics (summary.json): pure, no I/O.

Over trajectories, as the paper's Table I: success as a Laplace estimate, time, cosine
distance and agreement as geometric means (arithmetic means beside them, labelled); censored
times (the operator gave up, the time limit, an open-loop trial that never settled) are
counted. `compare` tests two modes on the same trajectories (N-1 chi-squared and McNemar on
success, t tests on the log time and the action metrics); `divergence` holds the
Jensen-Shannon divergences of Fig. 8's pairs; `fig5_remark` measures the paper's Fig. 5
remark; `headline` gives one mode's numbers flat, for tuning and tables.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.study.metric_table import Metric, table, tuning_key, tuning_order, variant_key
from dsteleop.app.study.planar import (
    Array,
    SimConfig,
    grasp_of,
    in_success_region,
    sample_closed_trial,
)
from dsteleop.app.study.results import PHASE_EDGES, VARIANTS, ModeResult, StudyResult
from dsteleop.arbitration import metrics

SCHEMA = "dsteleop.sim_summary/2"


def fig5_remark(res: StudyResult) -> dict[str, Any]:
    """The paper's Fig. 5 remark, measured: while the operator moves along y only, how much
    x the output adds per unit of y (sum |U_out,x| / sum |U_out,y| per trajectory), S vs DS,
    with the paired test (S minus DS)."""
    cfg = res.config
    out: dict[str, Any] = {
        "operator": cfg.operator,
        "trajectories": cfg.trajectories,
        "claim": (
            "paper Fig. 5/6: while the operator moves along y, S forces motion along x and DS "
            "keeps alpha_x low"
        ),
    }
    for name in ("S", "DS"):
        if name in res.modes:
            r = res.modes[name]
            out[name] = {
                "pooled": _safe_ratio(r.y_only[:, 0].sum(), r.y_only[:, 1].sum()),
                **_mean_ci(x_per_y(r)),
            }
    if "S" in res.modes and "DS" in res.modes:
        a, b = x_per_y(res.modes["S"]), x_per_y(res.modes["DS"])
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() >= 2:
            out["paired_t_S_minus_DS"] = dataclasses.asdict(metrics.paired_t_test(a[ok], b[ok]))
    return out


def summarise(res: StudyResult, figures: StudyResult | None = None) -> dict[str, Any]:
    """The summary.json object: per mode metrics, S vs DS tests, divergences, config, and
    the Fig. 5 remark from `figures` (the open-loop companion, `figure_study`; `res` itself
    when None)."""
    cfg = res.config
    modes: dict[str, Any] = {}
    for name, r in res.modes.items():
        modes[name] = {
            "n": int(r.success.size),
            **{m.summary_key: _metric_summary(cfg, m, r) for m in table()},
            "by_phase": {
                "edges": PHASE_EDGES.tolist(),
                "cosine_distance": _ratio(*r.phase_cos.sum(0)),
                "agreement": _ratio(*r.phase_agree.sum(0)),
            },
            "x_per_y_while_operator_moves_y_only": {
                "pooled": _safe_ratio(r.y_only[:, 0].sum(), r.y_only[:, 1].sum()),
                **_mean_ci(x_per_y(r)),
            },
            "gave_up_share": float(r.gave_up.mean()),
            "committed_share": float(r.committed.mean()),
            "runs": [_run_summary(r, r.attempt == a) for a in range(cfg.runs)],
            "metric_variants": _metric_variants(r),
        }
    out: dict[str, Any] = {
        "schema": SCHEMA,
        "seed": cfg.seed,
        "trajectories": cfg.trajectories,
        "runs": cfg.runs,
        "modes": modes,
        "tests": {},
        "divergence": fig8_divergences(
            {k: v.hand_hist for k, v in res.modes.items()},
            {k: v.hist for k, v in res.modes.items()},
        ),
        "operator": {
            "kind": cfg.operator,
            "closed_loop": cfg.closed_loop,
            "lead_share": float(res.lead.mean()),
            "trial_s": {
                name: _describe(np.asarray((r.lengths - 1) * cfg.dt_s, dtype=np.float64))
                for name, r in res.modes.items()
            },
        },
        "config": cfg.to_dict(),
        "fig5_fig6": fig5_remark(figures or res),
    }
    if "S" in res.modes and "DS" in res.modes:
        out["tests"]["S_vs_DS"] = compare(res.modes["S"], res.modes["DS"])
    if "scalar" in res.modes and "DS" in res.modes:
        # The tuned baseline with the same levers (docs/tuned/README.md) against DS.
        out["tests"]["scalar_vs_DS"] = compare(res.modes["scalar"], res.modes["DS"])
    if cfg.grasps is not None and cfg.closed_loop:
        out["disagreement"] = disagreement_summary(res)
    if cfg.objects is not None:
        out["objects"] = objects_summary(res)
    return out


#: The verdict of a paired comparison: a win or a loss where McNemar's exact p is below this.
ALPHA = 0.05


def versus(
    success_a: NDArray[np.bool_], success_b: NDArray[np.bool_], time_a: Array, time_b: Array
) -> dict[str, Any]:
    """Mode a against mode b on the same runs: the mean paired difference of success (a minus
    b) with its 95 % t interval, McNemar's exact and mid-p tests, the ratio of geometric-mean
    times (a over b) with its paired interval, and the verdict (`a wins` / `a loses` where
    McNemar's exact p < ALPHA, by the sign of the difference, else `tie`)."""
    a, b = success_a.astype(np.float64), success_b.astype(np.float64)
    mc = metrics.mcnemar(success_a, success_b)
    out: dict[str, Any] = {"n": int(a.size), "mcnemar": dataclasses.asdict(mc)}
    if a.size >= 2:
        diff = metrics.paired_difference(a, b)
        logd = metrics.paired_difference(np.log(time_a), np.log(time_b))
        out.update(
            success_difference=diff.mean,
            ci95=[diff.ci_low, diff.ci_high],
            time_ratio=math.exp(logd.mean),
            time_ratio_ci95=[math.exp(logd.ci_low), math.exp(logd.ci_high)],
        )
    d = float(a.mean() - b.mean()) if a.size else 0.0
    out["verdict"] = ("a wins" if d > 0 else "a loses") if mc.p_exact < ALPHA and d != 0 else "tie"
    return out


def objects_summary(res: StudyResult) -> dict[str, Any]:
    """The objects world's outcomes (docs/operator.md): per mode, over every run and apart
    for the runs in which the person kept its mind and those in which it changed it, the
    success, time, give-ups, failures at another object than the one wanted, and the robot's
    MAP object (right at the end, when it settled there, how often it switched); and DSC
    against every other mode on the same runs (`versus`)."""
    cfg = res.config
    assert cfg.objects is not None
    out: dict[str, Any] = {"objects": cfg.objects.to_dict(), "modes": {}, "DSC_versus": {}}
    for name, r in res.modes.items():
        groups = {"all": np.ones(r.success.size, dtype=bool), "kept_mind": ~r.changed}
        groups["changed_mind"] = r.changed
        out["modes"][name] = {k: _objects_group(r, rows) for k, rows in groups.items()}
    if "DSC" in res.modes:
        a = res.modes["DSC"]
        for name, b in res.modes.items():
            if name != "DSC":
                out["DSC_versus"][name] = versus(a.success, b.success, a.time_s, b.time_s)
    return out


def _objects_group(r: ModeResult, rows: NDArray[np.bool_]) -> dict[str, Any]:
    n = int(rows.sum())
    if n == 0:
        return {"n": 0}
    sr = metrics.success_rate(int(r.success[rows].sum()), n)
    wrong = r.committed & (r.grasped >= 0) & (r.grasped != r.wanted)
    right = r.map_final[rows] == r.wanted[rows]
    settled = r.map_settled_s[rows]
    return {
        "n": n,
        "success_rate": {"estimate": sr.laplace, "ci95": [sr.ci_low, sr.ci_high]},
        "time_s": metrics.geometric_mean(r.time_s[rows]).mean,
        "gave_up_share": float(r.gave_up[rows].mean()),
        "wrong_object_share": float(wrong[rows].mean()),
        "map_right_at_end_share": float(right.mean()),
        "map_settled_s_median": float(np.median(settled[right])) if right.any() else None,
        "map_switches_mean": float(r.map_switches[rows].mean()),
    }


def disagreement_summary(res: StudyResult) -> dict[str, Any]:
    """The disagreement world's outcomes, apart for the people who prefer the robot's grasp
    (they agree with it) and those who prefer the other (they disagree in the heading): per
    mode each group's success, time, give-ups, the share that switched to the robot's grasp,
    and which grasp the settled pose is in."""
    cfg = res.config
    g = cfg.grasps
    assert g is not None
    trials = [sample_closed_trial(cfg, n) for n in range(cfg.trajectories)]
    prefers = np.repeat(np.array([t.grasp for t in trials]), cfg.runs)
    robot = g.robot_index
    names = ("top", "side")
    groups = {"prefers_robot_grasp": prefers == robot, "prefers_other_grasp": prefers != robot}
    out: dict[str, Any] = {
        "grasps": g.to_dict(),
        "robot_grasp": g.robot_grasp,
        "people": {k: int(v.sum() // cfg.runs) for k, v in groups.items()},
        "modes": {},
    }
    for name, r in res.modes.items():
        final_grasp = grasp_of(cfg, r.final[:, 2])
        inside = in_success_region(
            r.final[:, :2], r.final[:, 2], cfg.handle_xy_m, cfg.grasp_headings,
            cfg.success_radius_m, cfg.success_heading_rad,
        )  # fmt: skip
        per: dict[str, Any] = {}
        for key, rows in groups.items():
            n = int(rows.sum())
            sr = metrics.success_rate(int(r.success[rows].sum()), n)
            ok = r.success[rows]
            per[key] = {
                "n": n,
                "success_rate": {"estimate": sr.laplace, "ci95": [sr.ci_low, sr.ci_high]},
                "time_s": metrics.geometric_mean(r.time_s[rows]).mean if n else None,
                "gave_up_share": float(r.gave_up[rows].mean()) if n else None,
                "switched_share": float(r.settled[rows].mean()) if n else None,
                "successes_in": {
                    names[k]: int((ok & (final_grasp[rows] == k)).sum()) for k in range(2)
                },
                "settled_in_a_grasp_share": float(inside[rows].mean()) if n else None,
            }
        out["modes"][name] = per
    return out


def _run_summary(r: ModeResult, rows: NDArray[np.bool_]) -> dict[str, float]:
    """One run's success (Laplace), time (geometric mean), shares and history term."""
    sr = metrics.success_rate(int(r.success[rows].sum()), int(rows.sum()))
    return {
        "n": int(rows.sum()),
        "success_rate": sr.laplace,
        "time_s": metrics.geometric_mean(r.time_s[rows]).mean,
        "committed_share": float(r.committed[rows].mean()),
        "gave_up_share": float(r.gave_up[rows].mean()),
        "history_term_l1": float(r.history_norm[rows].mean()),
    }


def _metric_summary(cfg: SimConfig, m: Metric, r: ModeResult) -> dict[str, Any]:
    """One mode's summary of the metric `m` over its trajectories (app/study/metric_table.py):
    a rate's Laplace estimate with its interval; otherwise the paper's Table I statistic, the
    geometric mean (`geometric`), with the metric's definition, its labelled variant and the
    study's own details of a known metric (`_DETAILS`)."""
    x = r.values[m.name]
    if m.scale == "rate":
        sr = metrics.success_rate(int(x.sum()), int(x.size))
        return {
            "estimate": sr.laplace,
            "ci95": [sr.ci_low, sr.ci_high],
            "successes": sr.successes,
            "n": sr.n,
        }
    out: dict[str, Any] = {"definition": m.about} if m.about else {}
    out.update(geometric(x))
    if m.variant is not None:
        out[m.variant.suffix] = {"label": m.variant.label, **_mean_ci(r.values[variant_key(m)])}
    details = _DETAILS.get(m.name)
    if details is not None:
        out.update(details(cfg, r))
    return out


#: The study's own details of the paper's metrics, beside their statistics in summary.json.
_DETAILS: dict[str, Callable[[SimConfig, ModeResult], dict[str, Any]]] = {
    "time_s": lambda cfg, r: {"censored": censoring(cfg, r)},
    "cosine_distance": lambda cfg, r: {
        "actions": int(r.n_actions.sum()),
        "skipped_idle": int(r.n_idle.sum()),
    },
    "agreement": lambda cfg, r: {"skipped_idle": int(r.n_idle.sum())},
}


def geometric(x: Array) -> dict[str, Any]:
    """Over trajectories, as the paper's Table I: the geometric mean of positive values with
    the 95 % interval of the log mean (None when a value is <= 0: `nonpositive` counts them),
    and beside it, labelled, the arithmetic mean with its t interval."""
    x = x[np.isfinite(x)]
    nonpositive = int(np.count_nonzero(x <= 0))
    gm = metrics.geometric_mean(x) if x.size and nonpositive == 0 else None
    ar = _mean_ci(x)
    return {
        "geometric_mean": None if gm is None else gm.mean,
        "ci95": [None, None] if gm is None else [gm.ci_low, gm.ci_high],
        "n": int(x.size),
        "nonpositive": nonpositive,
        "arithmetic_mean": ar["mean"],
        "arithmetic_ci95": ar["ci95"],
    }


def censored(cfg: SimConfig, r: ModeResult) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per trajectory, whether its time is censored: (gave up, ran to the limit). Closed
    loop: the operator gave up (its patience), or the trial ran to `max_trial_s`; open loop:
    a failed trial, whose time is the trial's end rather than a settling time."""
    if not cfg.closed_loop:
        return np.zeros_like(r.success), ~r.success
    limit = round(cfg.max_trial_s / cfg.dt_s) + 1
    return r.gave_up.copy(), (r.lengths >= limit) & ~r.gave_up


def censoring(cfg: SimConfig, r: ModeResult) -> dict[str, Any]:
    """Counts and share of the censored times of one mode (`censored`)."""
    gave_up, limit = censored(cfg, r)
    n = int(r.success.size)
    count = int(np.count_nonzero(gave_up | limit))
    return {
        "count": count,
        "share": count / n if n else None,
        "gave_up": int(gave_up.sum()),
        "time_limit": int(limit.sum()),
        "about": (
            "the operator gave up (patience) or the trial ran to the time limit: the time is a "
            "lower bound"
            if cfg.closed_loop
            else "open loop: a failed trial never settled; its time is the trial's end"
        ),
    }


#: The paper's Fig. 8 divergences (its human study; x, y, z positions), for reference.
PAPER_FIG8 = {
    "operator_DS~operator_S": 0.1293,
    "robot_DS~robot_S": 0.1896,
    "operator_DS~robot_DS": 0.2905,
    "operator_S~robot_S": 0.3017,
}


def fig8_divergences(
    operator: dict[str, NDArray[np.int64]], robot: dict[str, NDArray[np.int64]]
) -> dict[str, Any]:
    """Jensen-Shannon divergences (base 2) of Fig. 8's pairs of trajectory histograms, each
    mode's own: the operator (hand) under DS vs under S, the robot under DS vs under S, and
    the operator vs the robot of every mode. Pairs with an empty histogram are left out.

    Args:
        operator: per mode, the histogram of the operator's hand over that mode's trials.
        robot: per mode, the robot's histogram (same bins).
    """

    def jsd(a: NDArray[np.int64], b: NDArray[np.int64]) -> float | None:
        return metrics.js_divergence(a, b) if a.sum() > 0 and b.sum() > 0 else None

    pairs: dict[str, float | None] = {}
    if "S" in operator and "DS" in operator:
        pairs["operator_DS~operator_S"] = jsd(operator["DS"], operator["S"])
        pairs["robot_DS~robot_S"] = jsd(robot["DS"], robot["S"])
    per_mode = {m: jsd(operator[m], robot[m]) for m in operator}
    for m in ("DS", "S"):
        if m in per_mode:
            pairs[f"operator_{m}~robot_{m}"] = per_mode[m]
    return {
        "about": (
            "Fig. 8: Jensen-Shannon divergence (base 2, in [0, 1]) between histograms of "
            "trajectory points, each of the operator or the robot under one mode"
        ),
        "fig8": pairs,
        "operator_vs_robot": per_mode,
        "paper_fig8": PAPER_FIG8,
    }


def headline(r: ModeResult) -> dict[str, float]:
    """The headline numbers of one mode over its trajectories, flat (for tuning and tables),
    per metric of the table (app/study/metric_table.py) in tuning's order, then `gave_up`.

    Keys of a rate (`success`): its Laplace estimate under its name, its count
    (`successes`), `n` and its adjusted-Wald interval (`success_ci_low`/`_high`); of a log
    metric (`time_s`): its geometric mean; of a linear one (`cosine_distance`, `agreement`):
    the mean over trajectories of the value tuning optimises (the cosine distance per action,
    `Metric.tune_variant`; nan without any) and the half-width of its 95 % t interval
    (`<name>_ci_half`); `gave_up`: the share of trials the operator gave up.
    """
    out: dict[str, float] = {}
    for m in tuning_order():
        x = r.values[tuning_key(m)]
        if m.scale == "rate":
            sr = metrics.success_rate(int(x.sum()), int(x.size))
            out[m.name] = sr.laplace
            out[m.count_key] = float(sr.successes)
            out["n"] = float(sr.n)
            out[f"{m.name}_ci_low"] = sr.ci_low
            out[f"{m.name}_ci_high"] = sr.ci_high
        elif m.scale == "log":
            out[m.name] = metrics.geometric_mean(x).mean
        else:
            mc = _mean_ci(x)
            lo, hi = mc["ci95"]
            out[m.name] = math.nan if mc["mean"] is None else float(mc["mean"])
            out[f"{m.name}_ci_half"] = math.nan if lo is None else float(hi - lo) / 2.0
    out["gave_up"] = float(r.gave_up.mean())
    return out


def _metric_variants(r: ModeResult) -> dict[str, Any]:
    """`metric_variants` of one mode: the headline definitions and the others (see
    `_variants`), each the mean over trajectories with its 95 % interval."""
    out: dict[str, Any] = {
        "literal": {
            "about": "the paper's definitions on U in m/s and rad/s (the headline numbers)",
            "cosine_distance": _mean_ci(r.cosine_mean),
            "agreement": _mean_ci(r.agreement),
        }
    }
    for name, about in VARIANTS.items():
        out[name] = {
            "about": about,
            "cosine_distance": _mean_ci(r.variants[f"{name}.cosine_distance"]),
            "agreement": _mean_ci(r.variants[f"{name}.agreement"]),
        }
    out["fingers"] = {
        "about": "the planar study has no fingers",
        "cosine_distance": None,
        "agreement": None,
    }
    out["by_phase"] = {
        "about": "pooled over trajectories per decile of each trial's duration",
        "edges": PHASE_EDGES.tolist(),
        "cosine_distance": _ratio(*r.phase_cos.sum(0)),
        "agreement": _ratio(*r.phase_agree.sum(0)),
    }
    return out


def compare(a: ModeResult, b: ModeResult) -> dict[str, Any]:
    """Tests between two modes on the same trajectories (a minus b in the statistics), per
    metric of the table by its scale (a rate: the N-1 chi-squared and McNemar tests; a log
    metric: two-sample and paired t tests of the logs; a linear one: of the values, and so
    for its variant), then the paper's Fig. 5 remark (x added per y)."""
    out: dict[str, Any] = {"statistics_are": "first minus second mode"}
    for m in table():
        x, y = a.values[m.name], b.values[m.name]
        if m.scale == "rate":
            chi = metrics.n1_chi_squared(int(x.sum()), x.size, int(y.sum()), y.size)
            out[f"{m.test_key}_n1_chi2"] = dataclasses.asdict(chi)
            out[f"{m.test_key}_mcnemar"] = dataclasses.asdict(metrics.mcnemar(x, y))
            continue
        out[m.test_key] = _t_tests(x, y, log=m.scale == "log")
        if m.variant is not None:
            key = variant_key(m)
            out[key] = _t_tests(a.values[key], b.values[key], log=m.scale == "log")
    out["x_per_y_while_operator_moves_y_only"] = _t_tests(x_per_y(a), x_per_y(b))
    return out


def _t_tests(x: Array, y: Array, log: bool = False) -> dict[str, Any]:
    """Two-sample and paired t tests of x against y (of their logs with `log`; the pairs
    with a value that is not finite left out)."""
    if log:
        return {
            "two_sample_t": dataclasses.asdict(metrics.log_t_test(x, y)),
            "paired_t": dataclasses.asdict(metrics.paired_t_test(np.log(x), np.log(y))),
        }
    ok = np.isfinite(x) & np.isfinite(y)
    return {
        "two_sample_t": dataclasses.asdict(metrics.t_test(x[ok], y[ok])),
        "paired_t": dataclasses.asdict(metrics.paired_t_test(x[ok], y[ok])),
    }


def x_per_y(r: ModeResult) -> Array:
    """Per trajectory: sum |U_out_x| / sum |U_out_y| over the actions where the operator moves
    along y only (nan without such actions) - how much x the output adds (paper Fig. 5)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(
            r.y_only[:, 1] > 0, r.y_only[:, 0] / np.maximum(r.y_only[:, 1], 1e-300), np.nan
        )


def _safe_ratio(a: float, b: float) -> float | None:
    return float(a / b) if b > 0 else None


def _ratio(num: Array, den: Array) -> list[float | None]:
    return [float(a / b) if b > 0 else None for a, b in zip(num, den)]


def _mean_ci(x: Array) -> dict[str, Any]:
    x = x[np.isfinite(x)]
    n = int(x.size)
    if n == 0:
        return {"mean": None, "ci95": [None, None], "n": 0}
    m = float(x.mean())
    if n < 2:
        return {"mean": m, "ci95": [m, m], "n": n}
    half = metrics.t_quantile(0.975, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
    return {"mean": m, "ci95": [m - half, m + half], "n": n}


def _describe(x: Array) -> dict[str, float]:
    return {
        "mean": float(np.mean(x)),
        "min": float(np.min(x)),
        "median": float(np.median(x)),
        "max": float(np.max(x)),
    }
