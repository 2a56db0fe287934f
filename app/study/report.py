"""The study's written outputs: the JSON line on stdout and summary.md."""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.study.metric_table import Metric, table, variant_key


def brief(
    summary: dict[str, Any], out: Path, files: Sequence[str], elapsed_s: float, workers: int
) -> dict[str, Any]:
    """The JSON object printed on stdout: where the files are and the headline numbers."""
    modes = {name: _headline(m) for name, m in summary["modes"].items()}
    tests = summary["tests"].get("S_vs_DS")
    p = None
    if tests:
        p = {}
        for metric in table():
            p[metric.test_key] = _p_value(tests, metric)
            if metric.scale == "rate":
                p[f"{metric.test_key}_mcnemar_mid_p"] = tests[f"{metric.test_key}_mcnemar"]["p_mid"]
    fig = summary["fig5_fig6"]
    x_per_y = {k: fig[k]["mean"] for k in ("S", "DS") if k in fig}
    if "paired_t_S_minus_DS" in fig:
        x_per_y["p"] = fig["paired_t_S_minus_DS"]["p_value"]
    return {
        "out": str(out),
        "files": list(files),
        "operator": summary["operator"]["kind"],
        "fig5_operator": fig["operator"],
        "fig5_x_per_y": x_per_y,
        "trajectories": summary["trajectories"],
        "seed": summary["seed"],
        "modes": modes,
        "p_S_vs_DS": p,
        "workers": workers,
        "elapsed_s": round(elapsed_s, 3),
    }


def _headline(m: dict[str, Any]) -> dict[str, Any]:
    """One mode's numbers in the JSON line: each metric's Table I statistic (a rate's
    estimate, the others' geometric mean), its variant's mean and the censored share of the
    times."""
    out: dict[str, Any] = {}
    for metric in table():
        s = m[metric.summary_key]
        if metric.scale == "rate":
            out[metric.summary_key] = s["estimate"]
            continue
        out[metric.name] = s["geometric_mean"]
        if "censored" in s:
            out[f"{metric.short or metric.name}_censored_share"] = s["censored"]["share"]
        if metric.variant is not None:
            out[variant_key(metric)] = s[metric.variant.suffix]["mean"]
    return out


def markdown(summary: dict[str, Any]) -> str:
    """summary.md: the paper's Table I shape, then the tests and divergences."""
    tests = summary["tests"].get("S_vs_DS")
    # Bold marks the better of S and DS where the difference is significant (p < 0.05), as
    # in the paper's Table I.
    better: dict[str, str | None] = {}
    if tests:
        m = summary["modes"]
        for metric in table():
            stat = "estimate" if metric.scale == "rate" else "geometric_mean"
            s_val, ds_val = (m[x][metric.summary_key][stat] for x in ("S", "DS"))
            if s_val is not None and ds_val is not None and _p_value(tests, metric) < 0.05:
                better[metric.name] = "S" if metric.better(s_val, ds_val) else "DS"

    def cell(
        key: str, mode: str, est: float | None, ci: Sequence[float | None], digits: int
    ) -> str:
        if est is None:
            return "n/a"
        lo, hi = ci
        text = f"{est:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
        return f"**{text}**" if better.get(key) == mode else text

    op = summary["operator"]
    if op["closed_loop"]:
        about = (
            "The operator watches the robot (with a perception delay) and steers it to the TRUE "
            "handle; a trial ends when it is satisfied and holds, or gives up. This table is a "
            "simulated analogue of the paper's Table I (a study with ten people), shaped like "
            "it: it is not that study, and its numbers are not Table I's."
        )
    else:
        about = (
            f"The operator (`{op['kind']}`) follows a sampled trajectory and does not watch the "
            "robot, as in the paper's simulation: it reproduces the qualitative claims of "
            "Fig. 5/6 (below); it cannot correct the robot, so its aggregate table cannot "
            "speak to the paper's Table I."
        )
    lines = [
        f"# Simulation study: {summary['trajectories']} trajectories, seed {summary['seed']}, "
        f"operator `{op['kind']}`",
        "",
        about,
        "",
        "The paper's definitions and statistics (Section IV-D, Table I), with 95 % confidence "
        "intervals: success as a Laplace estimate with the adjusted-Wald interval; trial time, "
        "cosine distance and ratio of agreement as geometric means over trajectories with the "
        "interval of the log mean. The cosine distance of a trajectory is the paper's SUM over "
        "its actions (not a mean per action: that is beside it below, labelled). Both action "
        "metrics skip the same idle actions (|U_h| or |U_out| <= 1e-9: no direction). "
        "n/a: a value <= 0 leaves no geometric mean. Bold: better of S and DS with p < 0.05.",
        "",
        "| Mode | " + " | ".join(_table_i(m)[0] for m in table()) + " |",
        "| --- |" + " --- |" * len(table()),
    ]
    for name, m in summary["modes"].items():
        cells = []
        for metric in table():
            s = m[metric.summary_key]
            est = s["estimate"] if metric.scale == "rate" else s["geometric_mean"]
            cells.append(cell(metric.name, name, est, s["ci95"], _table_i(metric)[1]))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Beside the paper's statistics, labelled: arithmetic means (time, cosine distance sum, "
        "agreement), the cosine distance as a mean per action, the idle actions both metrics "
        "skipped, and the censored times ("
        + next(iter(summary["modes"].values()))["time_s"]["censored"]["about"]
        + ").",
        "",
        "| Mode | Time, arithmetic (s) | Censored times | Cosine distance sum, arithmetic "
        "| Cosine distance per action (labelled) | Agreement, arithmetic | Idle actions skipped |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, m in summary["modes"].items():
        t, c, a = m["time_s"], m["cosine_distance"], m["agreement"]
        cen = t["censored"]
        share = "n/a" if cen["share"] is None else f"{cen['share']:.1%}"
        lines.append(
            f"| {name} | {_mean(t['arithmetic_mean'], t['arithmetic_ci95'], 2)} | "
            f"{cen['count']} of {t['n']} ({share}) | "
            f"{_mean(c['arithmetic_mean'], c['arithmetic_ci95'], 2)} | "
            f"{_mean(c['per_action_mean']['mean'], c['per_action_mean']['ci95'], 3)} | "
            f"{_mean(a['arithmetic_mean'], a['arithmetic_ci95'], 3)} | "
            f"{c['skipped_idle']} of {c['skipped_idle'] + c['actions']} |"
        )
    if op["closed_loop"]:
        ended = ", ".join(
            f"{name} {m['gave_up_share']:.0%}" for name, m in summary["modes"].items()
        )
        lines += [
            "",
            f"Trials that ended with the operator giving up (patience): {ended}; the others "
            "ended satisfied. A trial's time is its duration, so where most give up it is mostly "
            "the patience limit.",
        ]
    for pair, (first, second) in (("S_vs_DS", ("S", "DS")), ("scalar_vs_DS", ("scalar", "DS"))):
        if pair in summary["tests"]:
            lines += _tests_section(summary["tests"][pair], first, second)
    lines += _runs_table(summary)
    lines += _variants_table(summary)
    lines += _fig5_section(summary["fig5_fig6"])
    lines += ["", "## Cosine distance and agreement by phase of the trial (deciles)", ""]
    edges = next(iter(summary["modes"].values()))["by_phase"]["edges"]
    head = " | ".join(f"{a:.1f}-{b:.1f}" for a, b in itertools.pairwise(edges))
    lines += [f"| Mode | Metric | {head} |", "| --- | --- |" + " --- |" * (len(edges) - 1)]
    for name, m in summary["modes"].items():
        for key, label in (("cosine_distance", "cosine"), ("agreement", "agreement")):
            vals = " | ".join("n/a" if v is None else f"{v:.3f}" for v in m["by_phase"][key])
            lines.append(f"| {name} | {label} | {vals} |")
    lines += divergence_section(summary["divergence"], "(x, y, heading)")
    if "disagreement" in summary:
        lines += disagreement_section(summary["disagreement"])
    if "objects" in summary:
        lines += objects_section(summary["objects"])
    c = summary["config"]
    lines += [
        "",
        "## Configuration",
        "",
        f"- handle at {c['handle_xy_m']} m, normal {c['handle_normal_rad']:.4f} rad; success R = "
        f"{c['success_radius_m']} m, delta = {c['success_heading_rad']} rad",
        f"- world (docs/operator.md): {json.dumps(c['world'], sort_keys=True)}; dt = "
        f"{c['dt_s']:.5f} s; runs per person and mode: {summary['runs']}",
        f"- arbitration: {json.dumps(c['arbitration'], sort_keys=True)}",
        "",
    ]
    return "\n".join(lines)


def disagreement_section(d: dict[str, Any]) -> list[str]:
    """The disagreement world's table: each mode's outcomes for the people who prefer the
    robot's grasp and for those who prefer the other, apart."""
    g = d["grasps"]
    lines = [
        "",
        "## The disagreement world: people who agree with the robot's grasp, and who do not",
        "",
        f"Two right grasps (top at the normal, side {g['separation_rad']:.4f} rad from it); the "
        f"robot goes to `{d['robot_grasp']}`; {d['people']['prefers_robot_grasp']} people prefer "
        f"it, {d['people']['prefers_other_grasp']} the other; each switches to the robot's grasp "
        f"at a resistance pause with its own probability, U({g['adaptability'][0]:g}, "
        f"{g['adaptability'][1]:g}) (docs/operator.md).",
        "",
        "| Mode | People | Success [95 % CI] | Time [s] | Gave up | Switched "
        "| Successes top / side |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    labels = {"prefers_robot_grasp": "agree", "prefers_other_grasp": "disagree"}
    for name, per in d["modes"].items():
        for key, label in labels.items():
            r = per[key]
            if not r["n"]:
                continue
            sr = r["success_rate"]
            lo, hi = sr["ci95"]
            lines.append(
                f"| {name} | {label} ({r['n']} runs) | {sr['estimate']:.3f} [{lo:.3f}, {hi:.3f}] "
                f"| {r['time_s']:.2f} | {r['gave_up_share']:.3f} | {r['switched_share']:.3f} "
                f"| {r['successes_in']['top']} / {r['successes_in']['side']} |"
            )
    return lines


def objects_section(d: dict[str, Any]) -> list[str]:
    """The objects world's tables: each mode's outcomes and its MAP object, over every run and
    apart for the runs with and without a change of mind; then DSC against each mode."""
    o = d["objects"]
    lines = [
        "",
        "## The objects world: the robot infers which object the person wants",
        "",
        f"{o['count']} objects {o['spacing_m']:g} m apart; the robot's perception error "
        f"{1000 * o['perception_depth_m']:g} mm along its view, "
        f"{1000 * o['perception_lateral_m']:g} mm across, {o['perception_heading_rad']:g} rad "
        f"in the heading; the person changes its mind in a share {o['change_share']:g} of runs "
        f"(docs/operator.md).",
        "",
        "| Mode | Runs | Success [95 % CI] | Time [s] | Gave up | Wrong object "
        "| MAP right at the end | MAP settled [s], median | MAP switches |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    labels = {"all": "all", "kept_mind": "kept its mind", "changed_mind": "changed its mind"}
    for name, per in d["modes"].items():
        for key, label in labels.items():
            r = per[key]
            if not r["n"]:
                continue
            sr = r["success_rate"]
            lo, hi = sr["ci95"]
            settled = r["map_settled_s_median"]
            lines.append(
                f"| {name} | {label} ({r['n']}) | {sr['estimate']:.3f} [{lo:.3f}, {hi:.3f}] "
                f"| {r['time_s']:.2f} | {r['gave_up_share']:.3f} | {r['wrong_object_share']:.3f} "
                f"| {r['map_right_at_end_share']:.3f} | "
                f"{'n/a' if settled is None else f'{settled:.2f}'} | {r['map_switches_mean']:.2f} |"
            )
    if d["DSC_versus"]:
        lines += [
            "",
            "DSC against each mode on the same runs (success difference DSC minus the mode, "
            "McNemar's exact p; a win or a loss where p < 0.05; time ratio DSC / the mode):",
            "",
            "| Versus | Success difference [95 % CI] | McNemar exact p | Verdict for DSC "
            "| Time ratio [95 % CI] |",
            "| --- | --- | --- | --- | --- |",
        ]
        for name, v in d["DSC_versus"].items():
            lo, hi = v.get("ci95", (float("nan"), float("nan")))
            tlo, thi = v.get("time_ratio_ci95", (float("nan"), float("nan")))
            verdict = v["verdict"].replace("a ", "DSC ")
            lines.append(
                f"| {name} | {v.get('success_difference', float('nan')):+.3f} [{lo:+.3f}, "
                f"{hi:+.3f}] | {_p(v['mcnemar']['p_exact'])} | {verdict} | "
                f"x{v.get('time_ratio', float('nan')):.2f} [{tlo:.2f}, {thi:.2f}] |"
            )
    return lines


def _runs_table(summary: dict[str, Any]) -> list[str]:
    """Success, time and give-ups per run of each person (run 1 has no history term)."""
    lines = [
        "",
        "## Per run (each person's runs in each mode; eq (6)'s history term from run 2 on)",
        "",
        "| Mode | Run | Success | Time [s] | Committed | Gave up | mean abs history term |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, m in summary["modes"].items():
        for k, r in enumerate(m["runs"]):
            lines.append(
                f"| {name} | {k + 1} | {r['success_rate']:.3f} | {r['time_s']:.2f} | "
                f"{r['committed_share']:.3f} | {r['gave_up_share']:.3f} | "
                f"{r['history_term_l1']:.3f} |"
            )
    return lines


def _variants_table(summary: dict[str, Any]) -> list[str]:
    modes = summary["modes"]
    first = next(iter(modes.values()))["metric_variants"]
    names = [
        k
        for k, v in first.items()
        if isinstance(v, dict) and isinstance(v.get("cosine_distance"), dict)
    ]
    lines = [
        "",
        "## Metric variants (mean cosine distance / ratio of agreement)",
        "",
        "The headline is `literal`. The others change one thing each:",
        "",
    ]
    lines += [f"- `{k}`: {first[k]['about']}" for k in names]
    lines += ["", "| Mode | " + " | ".join(names) + " |", "| --- |" + " --- |" * len(names)]

    def fmt(v: dict[str, Any]) -> str:
        c, a = v["cosine_distance"]["mean"], v["agreement"]["mean"]
        return "n/a" if c is None or a is None else f"{c:.3f} / {a:.3f}"

    for name, m in modes.items():
        mv = m["metric_variants"]
        lines.append(f"| {name} | " + " | ".join(fmt(mv[k]) for k in names) + " |")
    return lines


def _fig5_section(fig: dict[str, Any]) -> list[str]:
    lines = [
        "",
        f"## Fig. 5/6: the open-loop `{fig['operator']}` operator, {fig['trajectories']} "
        "trajectories",
        "",
        f"Claim ({fig['claim']}). While the operator moves along y only, the output's x motion "
        "per unit of y motion (sum |U_out,x| / sum |U_out,y|, per trajectory):",
        "",
    ]
    for k in ("S", "DS"):
        if k in fig and fig[k]["mean"] is not None:
            lo, hi = fig[k]["ci95"]
            lines.append(f"- {k}: {fig[k]['mean']:.3f} [{lo:.3f}, {hi:.3f}] (n = {fig[k]['n']})")
    if "paired_t_S_minus_DS" in fig:
        t = fig["paired_t_S_minus_DS"]
        lines.append(f"- paired t (S minus DS): t = {t['t']:.2f}, p = {_p(t['p_value'])}")
    lines.append("")
    lines.append("The figures fig5b-d and fig6 are drawn from this operator.")
    return lines


def divergence_section(div: dict[str, Any], space: str) -> list[str]:
    """The Fig. 8 divergences as a markdown section (`core.fig8_divergences`)."""
    lines = [
        "",
        f"## Fig. 8: Jensen-Shannon divergences of {space} histograms (base 2)",
        "",
        "Each histogram holds the trajectory points of the operator (hand) or of the robot "
        "under one mode, as the paper's Fig. 8 (a) operator DS, (b) operator S, (c) robot DS, "
        "(d) robot S. The paper's values come from its human study (x, y, z), for reference.",
        "",
        "| Pair | JSD | paper |",
        "| --- | --- | --- |",
    ]
    paper = div.get("paper_fig8", {})
    for k, v in div["fig8"].items():
        ref = paper.get(k)
        lines.append(
            f"| {k} | {'n/a' if v is None else f'{v:.4f}'} | "
            f"{'' if ref is None else f'{ref:.4f}'} |"
        )
    lines += ["", "Operator vs robot, every mode:", ""]
    lines += [
        f"- {m}: {'n/a' if v is None else f'{v:.4f}'}" for m, v in div["operator_vs_robot"].items()
    ]
    return lines


def _tests_section(tests: dict[str, Any], first: str, second: str) -> list[str]:
    """The tests between two modes on the same trajectories (`core.compare`)."""
    lines = [
        "",
        f"## {first} vs {second} (same trajectories)",
        "",
        "| Metric | Test | Statistic | p |",
        "| --- | --- | --- | --- |",
    ]
    for metric in table():
        if metric.scale == "rate":
            chi = tests[f"{metric.test_key}_n1_chi2"]
            lines += [
                f"| {metric.name} | N-1 chi-squared | {chi['chi2']:.3f} | {_p(chi['p_value'])} |",
                _mcnemar_row(tests[f"{metric.test_key}_mcnemar"], first, second, metric.name),
            ]
    for metric in table():
        if metric.scale == "rate":
            continue
        keys = [(metric.test_key, _TEST_LABELS.get(metric.name, metric.label))]
        if metric.variant is not None:
            label = _TEST_LABELS.get(variant_key(metric), f"{metric.label} {metric.variant.suffix}")
            keys.append((variant_key(metric), label))
        for key, label in keys:
            for test, tlabel in (("two_sample_t", "two-sample t"), ("paired_t", "paired t")):
                r = tests[key][test]
                lines.append(f"| {label} | {tlabel} | {r['t']:.3f} | {_p(r['p_value'])} |")
    return lines


def _mcnemar_row(t: dict[str, Any], first: str, second: str, name: str = "success") -> str:
    return (
        f"| {name} | McNemar (paired; {t['first_only']} {first} only, "
        f"{t['second_only']} {second} only) "
        f"| exact p {_p(t['p_exact'])} | mid-p {_p(t['p_mid'])} |"
    )


#: The paper's Table I: its column heading and the digits of each of its metrics (another
#: metric: its heading with the unit, 3 digits).
_TABLE_I: dict[str, tuple[str, int]] = {
    "success": ("Success Rate", 3),
    "time_s": ("Trial Time (s)", 2),
    "cosine_distance": ("Cosine Distance", 2),
    "agreement": ("Ratio of Agreement", 3),
}
#: The words of the tests' table for the paper's metrics (another one: its label).
_TEST_LABELS = {
    "time_s": "log time",
    "cosine_distance": "cosine distance (sum)",
    "cosine_distance_per_action_mean": "cosine distance per action (labelled)",
    "agreement": "agreement",
}


def _table_i(m: Metric) -> tuple[str, int]:
    return _TABLE_I.get(m.name, (m.heading, 3))


def _p_value(tests: dict[str, Any], m: Metric) -> float:
    """The p-value that marks a metric's difference in Table I: the N-1 chi-squared test's
    for a rate, the two-sample t test's otherwise (of the logs for a log metric)."""
    if m.scale == "rate":
        return float(tests[f"{m.test_key}_n1_chi2"]["p_value"])
    return float(tests[m.test_key]["two_sample_t"]["p_value"])


def _mean(m: float | None, ci: Sequence[float | None], digits: int) -> str:
    if m is None:
        return "n/a"
    lo, hi = ci
    if lo is None or hi is None:
        return f"{m:.{digits}f}"
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _p(p: float) -> str:
    return f"{p:.3g}" if p >= 1e-300 else "< 1e-300"
