"""The tuning study's written outputs: trials.csv, best.json, summary.md, summary.json.

trials.csv    one row per finished trial, in trial order: number, state (COMPLETE or
              FAIL), the objective's value, whether the constraint held, the parameters,
              the constraint per source, every metric (`<source>.<MODE>.<metric>`),
              the trial's own compute time and its wall time [s], and the error of a
              failed trial
best.json     the best configuration as `{"arbitration": {...}, "objective": {...},
              "note": ..., "schema": ...}`: every field of the arbitration configuration,
              so `dsteleop run|serve|sim --config DIR/best.json` takes it as is
summary.md    what was searched, the objective, the best configuration and its gain over
              the base configuration on held-out data, with intervals
summary.json  the same, machine-readable
"""

from __future__ import annotations

import csv
import math
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.study import metric_table
from dsteleop.app.tune.driver import TrialRecord, TuneSettings
from dsteleop.app.tune.trial import describe_world

BEST_SCHEMA = "dsteleop.tune_best/1"
SUMMARY_SCHEMA = "dsteleop.tune_summary/1"


def order() -> tuple[str, ...]:
    """Per-mode metric keys in report order: each metric in tuning's order with its count and
    interval (`app.study.summary.headline`), then `gave_up` (the rest follow alphabetically)."""
    out: list[str] = []
    for m in metric_table.tuning_order():
        out.append(m.name)
        if m.scale == "rate":
            out += [m.count_key, "n", f"{m.name}_ci_low", f"{m.name}_ci_high"]
        elif m.scale == "linear":
            out.append(f"{m.name}_ci_half")
    return (*out, "gave_up")


def metric_columns(recs: Sequence[TrialRecord]) -> list[str]:
    names = {k for r in recs for k in r.metrics}
    keys = order()

    def rank(k: str) -> tuple[int, int, int, str]:
        parts = k.split(".")
        source = 0 if parts[0] == "study" else 1
        if len(parts) == 2:  # <source>.seconds
            return (source, 9, 0, k)
        mode = 0 if parts[1] == "S" else 1  # then the tuned mode
        m = keys.index(parts[2]) if parts[2] in keys else len(keys)
        return (source, mode, m, k)

    return sorted(names, key=rank)


def write_trials_csv(settings: TuneSettings, recs: Sequence[TrialRecord], path: Path) -> None:
    params = [d.name for d in settings.space]
    sources = settings.objective.sources if settings.objective.constrained else ()
    metrics = metric_columns(recs)
    header = [
        "number", "state", "value", "feasible", *params,
        *(f"constraint.{s}" for s in sources), *metrics, "seconds", "wall_s", "error",
    ]  # fmt: skip
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        for r in sorted(recs, key=lambda r: r.number):
            cons = list(r.constraints) + [None] * (len(sources) - len(r.constraints))
            w.writerow(
                [
                    r.number, r.state, _cell(r.value),
                    "" if r.state != "COMPLETE" else int(r.feasible),
                    *(_cell(r.params.get(p)) for p in params),
                    *(_cell(c) for c in cons[: len(sources)]),
                    *(_cell(r.metrics.get(m)) for m in metrics),
                    _cell(round(r.seconds, 3)), _cell(round(r.wall_s, 3)), r.error,
                ]
            )  # fmt: skip


def _cell(v: Any) -> Any:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    return v


def best_json(
    settings: TuneSettings, best: TrialRecord, holdout: Mapping[str, Any] | None, out: Path
) -> dict[str, Any]:
    """best.json's object (module docstring)."""
    objective: dict[str, Any] = {
        **settings.objective.to_dict(),
        "trial": best.number,
        "value": best.value,
        "params": best.params,
    }
    if holdout and "study" in holdout:
        g = holdout["study"][f"gain_{settings.mode}"]
        objective["holdout_gain_over_base"] = {
            "trajectories": holdout["study"]["trajectories"],
            "seed": holdout["study"]["seed"],
            "agreement": g["agreement"],
            "success": g["success"],
        }
    world = describe_world(settings.world)
    return {
        "schema": BEST_SCHEMA,
        "arbitration": settings.arbitration(best.params),
        "objective": objective,
        "world": {"overrides": dict(settings.world), "statement": world},
        "note": (
            f"written by dsteleop tune into {out}, tuned in {world}; use it with "
            f"dsteleop run|serve|sim --config {out / 'best.json'} (sim: with the same world "
            "options to score the world it was tuned in)"
        ),
    }


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, int):
        return str(v)
    return f"{v:.{digits}g}" if abs(float(v)) >= 1000 else f"{float(v):.{digits}f}"


def _p(v: Any) -> str:
    """A p-value: two decimals, or one significant digit below 0.01."""
    if v is None or not math.isfinite(float(v)):
        return "-"
    if v == 0:
        return "< 1e-300"  # below what a double holds
    return f"{v:.2f}" if v >= 0.01 else f"{v:.1g}"


def _ci(d: Mapping[str, Any], digits: int = 3) -> str:
    lo, hi = d["ci95"]
    return f"{_fmt(d['mean'], digits)} [{_fmt(lo, digits)}, {_fmt(hi, digits)}]"


def power(settings: TuneSettings, recs: Sequence[TrialRecord]) -> dict[str, Any]:
    """The tuning batch's resolution: the median over complete trials of the 95 % interval
    half-width of each of the tuned mode's metrics that has one (a rate, a linear metric:
    `<name>_ci_half`)."""
    done = [r for r in recs if r.state == "COMPLETE"]
    if settings.batch is None or not done:
        return {}

    def med(name: str) -> float | None:
        xs = [r.metrics.get(name, math.nan) for r in done]
        xs = [x for x in xs if math.isfinite(x)]
        return statistics.median(xs) if xs else None

    mode = settings.mode
    out: dict[str, Any] = {"trajectories": settings.batch.trajectories}
    for m in _intervals_first():
        if m.scale == "rate":
            lo, hi = med(f"study.{mode}.{m.name}_ci_low"), med(f"study.{mode}.{m.name}_ci_high")
            out[f"{m.name}_ci_half"] = None if lo is None or hi is None else (hi - lo) / 2.0
        elif m.scale == "linear":
            out[f"{m.name}_ci_half"] = med(f"study.{mode}.{m.name}_ci_half")
    return out


def markdown(summary: Mapping[str, Any]) -> str:
    """summary.md from summary.json's object."""
    st = summary["settings"]
    mode = st.get("mode", "DS")
    lines = [f"# dsteleop tune: {summary['out']}", ""]
    lines += ["## What was searched", ""]
    lines.append(
        ("The final campaign: " if len(summary.get("rounds") or []) > 1 else "")
        + f"{summary['trials']['finished']} trials ({summary['trials']['complete']} complete, "
        f"{summary['trials']['failed']} failed), sampler `{st['sampler']}` with seed "
        f"{st['seed']}"
        + (f", {st['grid_points']} values per range" if st["sampler"] == "grid" else "")
        + "; trials ran as Ray tasks on "
        + (
            "a local cluster"
            if summary["cluster"]["cluster"] == "local"
            else f"the cluster at {summary['cluster']['cluster']}"
        )
        + f" ({summary['cluster']['cpus']} CPUs)."
    )
    budget = summary.get("budget")
    if budget:
        lines.append(
            f"The budget: {budget['trials']} trials per campaign ({budget['rule']}); a "
            "comparison of modes is fair when each gets the same trials per parameter "
            "(docs/tune.md)."
        )
    lines.append("")
    rounds = summary.get("rounds") or []
    first = rounds[0]["space"] if rounds else st["space"]
    widened = len(rounds) > 1
    header = "| parameter | searched over | base value |"
    if widened:
        header = "| parameter | first searched over | finally searched over | base value |"
    lines += [header, "| --- " * (header.count("|") - 1) + "|"]
    for spec, first_spec in zip(st["space"], first):
        name, _, rng = spec.partition("=")
        cells = [f"`{name}`", f"`{first_spec.partition('=')[2]}`"]
        if widened:
            cells.append(f"`{rng}`")
        cells.append(_fmt(st["base"][name], 4))
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    src = []
    if st["trajectories"] is not None:
        src.append(
            f"the closed-loop study (docs/sim.md): trajectories 0-{st['trajectories'] - 1} of "
            f"seed {st['study_seed']}, the same for every trial, S and {mode} paired"
        )
    if st["sessions"]:
        src.append(
            f"{len(st['sessions'])} recorded session(s) replayed headless in S and {mode} with a "
            "fresh simulated robot: " + ", ".join(f"`{Path(p).name}`" for p in st["sessions"])
        )
    lines.append("Each trial evaluated one configuration on " + "; and ".join(src) + ".")
    world = summary.get("world")
    if world and st["trajectories"] is not None:
        lines.append(
            f"The study ran in {world['statement']}, the tuning trajectories and the held-out "
            "ones alike (`dsteleop sim` scores the same world with the same options)."
        )
    if summary.get("base_is_default"):
        lines.append("The base configuration is the default one (docs/METHOD.md §6).")
    else:
        lines.append("The base configuration came from `--config`/`--param` (summary.json).")
    lines += ["", "## The objective", "", summary["objective"]["statement"] + ".", ""]
    best = summary["best"]
    lines += ["## The best configuration", ""]
    if best is None:
        lines += [
            "No complete trial met the constraint, so there is no best configuration and no "
            "best.json.",
            "",
        ]
    else:
        lines.append(
            f"Trial {best['number']}: objective {_fmt(best['value'], 4)} on the tuning data "
            "(optimistic: the best of all trials on the same data; the held-out evaluation "
            "below is not). `best.json` holds the full configuration:"
        )
        lines += ["", "| parameter | best | base |", "| --- | --- | --- |"]
        for name, v in best["params"].items():
            lines.append(f"| `{name}` | {_fmt(v, 4)} | {_fmt(st['base'][name], 4)} |")
        lines += ["", "On the tuning data:", ""]
        lines += _mode_table(best["metrics"], summary["objective"]["sources"], mode)
    lines += _edges_md(summary)
    lines += _holdout_md(summary.get("holdout"), mode)
    pw = summary.get("power") or {}
    if pw:
        lines += [
            "",
            "## Resolution of a trial",
            "",
            f"A trial scores {mode} on {pw['trajectories']} trajectories: the median 95 % "
            f"interval half-width over trials is {_widths(pw)}. Trials share their "
            "trajectories, so differences between configurations are paired and finer than "
            "these intervals; a difference much smaller than them is still within what a "
            "different batch of trajectories could change.",
        ]
    failed = summary["trials"]["errors"]
    if failed:
        lines += ["", "## Failed trials", "", "| error | trials |", "| --- | --- |"]
        for err, numbers in failed.items():
            lines.append(f"| {err} | {', '.join(str(n) for n in numbers)} |")
    t = summary["timing"]
    lines += [
        "",
        "## Time",
        "",
        f"{_fmt(t['wall_s'], 1)} s in all ({_fmt(t['trials_wall_s'], 1)} s for the "
        f"{t['trials_run']} trials of this run: {_fmt(t['trials_per_minute'], 2)} trials per "
        f"minute; cluster start {_fmt(t['cluster_start_s'], 1)} s).",
        "",
        "Files: " + ", ".join(f"`{f}`" for f in summary["files"]),
        "",
    ]
    return "\n".join(lines)


def _intervals_first() -> list[metric_table.Metric]:
    """The metrics in tuning's order, those with a t interval (linear) before the rates."""
    return sorted(metric_table.tuning_order(), key=lambda m: m.scale == "rate")


def _widths(pw: Mapping[str, Any]) -> str:
    """`power`'s half-widths in words: "+-x for the success rate, ... and +-z for the ..."."""
    parts = [
        f"+-{_fmt(pw[f'{m.name}_ci_half'])} for the {m.label}"
        for m in _intervals_first()
        if f"{m.name}_ci_half" in pw
    ]
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def _edges_md(summary: Mapping[str, Any]) -> list[str]:
    """The campaigns (the first and each widening round) and the final best's edges."""
    rounds = summary.get("rounds")
    if rounds is None:
        return []
    out = ["", "## Edges of the search space", ""]
    n = summary.get("widen_edges", 0)
    out.append(
        "A best value within 5 % of its range's width (log width for a log range) of a range "
        "end is on an edge: the optimum may lie beyond it. "
        + (
            f"With up to {n} widening round(s), such a range is widened on that side (a log "
            "range by a factor of 4, a linear one by half its width, clipped to the field's "
            "domain) and a fresh campaign with the same budget searches the widened space; "
            "the best above is the last campaign's."
            if n
            else "Widening was off (--widen-edges 0)."
        )
    )
    if len(rounds) > 1:
        out += ["", "| campaign | searched | trials | best value | edges of its best |"]
        out.append("| --- | --- | --- | --- | --- |")
        for r in rounds:
            name = "first" if r["round"] == 0 else f"widening round {r['round']}"
            best = r["best"]
            found = (
                "; ".join(f"{e['name']} {e['side']} ({e['status']})" for e in r["edges"]) or "none"
            )
            out.append(
                f"| {name} | `{' '.join(r['space'])}` | {r['trials']} | "
                f"{_fmt(None if best is None else best['value'], 4)} | {found} |"
            )
    edges = summary.get("edges") or []
    out.append("")
    if not edges:
        out.append("No value of the final best is on an edge of its range.")
        return out
    out += ["The final best's values on an edge:", ""]
    out += ["| parameter | best | range end | distance | what was done |"]
    out.append("| --- | --- | --- | --- | --- |")
    for e in edges:
        out.append(
            f"| `{e['name']}` | {_fmt(e['value'], 4)} | {e['side']}: {_fmt(e['end'], 4)} | "
            f"{100 * e['distance']:.1f} % | {e['status_text']} |"
        )
    return out


def _mode_table(metrics: Mapping[str, float], sources: Sequence[str], tuned: str) -> list[str]:
    table = metric_table.tuning_order()
    rows = ["| source | mode | " + " | ".join(m.heading for m in table) + " |"]
    rows.append("| --- | --- |" + " --- |" * len(table))
    for s in sources:
        for mode in ("S", tuned):
            vals = [_fmt(metrics.get(f"{s}.{mode}.{m.name}")) for m in table]
            rows.append(f"| {s} | {mode} | " + " | ".join(vals) + " |")
    return rows


def _holdout_cell(m: metric_table.Metric, v: Mapping[str, Any]) -> str:
    """One metric of one configuration and mode on held-out data (`headline`'s numbers)."""
    if m.scale == "rate":
        lo, hi = v[f"{m.name}_ci_low"], v[f"{m.name}_ci_high"]
        return f"{_fmt(v[m.name])} [{_fmt(lo)}, {_fmt(hi)}]"
    if m.scale == "log":
        return _fmt(v[m.name], 2)
    return f"{_fmt(v[m.name])} +- {_fmt(v[f'{m.name}_ci_half'])}"


def _holdout_md(h: Mapping[str, Any] | None, tuned: str) -> list[str]:
    if not h:
        return [
            "",
            "## Held-out evaluation",
            "",
            "None was run (no best configuration, or `--holdout-trajectories 0`).",
        ]
    out = ["", "## Held-out evaluation", ""]
    if "error" in h:
        out.append(f"It could not run: {h['error']}")
    if "study" in h:
        s = h["study"]
        seen = (
            f"the tuning used seed {s['tuning_seed']}, so none of them was seen while tuning"
            if s["tuning_seed"] is not None
            else "the study was not an objective of this tuning: an independent check"
        )
        out.append(
            f"The base and the best configuration on {s['trajectories']} fresh trajectories of "
            f"the closed-loop study (seed {s['seed']}; {seen}), S and {tuned} paired; 95 % "
            "intervals:"
        )
        table = metric_table.tuning_order()
        out += [
            "",
            "| configuration | mode | "
            + " | ".join(m.name if m.scale == "rate" else m.heading for m in table)
            + " |",
            "| --- | --- |" + " --- |" * len(table),
        ]
        for name in ("base", "best"):
            for mode in ("S", tuned):
                cells = [_holdout_cell(m, s[name][mode]) for m in table]
                out.append(f"| {name} | {mode} | " + " | ".join(cells) + " |")
        g = s[f"gain_{tuned}"]
        out += [
            "",
            f"Gain of the best configuration's {tuned} over the base's {tuned} (mean paired "
            "difference "
            "over trajectories, 95 % interval, paired t-test p):",
            "",
            "| metric | best - base | p |",
            "| --- | --- | --- |",
        ]
        for m in table:
            if m.scale == "log":
                ratio = g[f"{m.short or m.name}_ratio"]
                out.append(f"| {m.short or m.name} (ratio of geometric means) | {_ci(ratio)} | |")
            else:
                what = f"{m.name} (share)" if m.scale == "rate" else m.label
                out.append(f"| {what} | {_ci(g[m.name])} | {_p(g[m.name]['p_value'])} |")
        c = s[f"tuned_{tuned}_vs_S"]
        out += [
            "",
            f"The constraint on the held-out trajectories: the best configuration's {tuned} "
            f"succeeded {c[f'successes_{tuned}']} times, its S {c['successes_S']} times of "
            f"{c['n']} ({'met' if c['constraint_met'] else 'NOT met'}; N-1 chi-squared p = "
            f"{_p(c['success_n1_chi2_p'])}).",
        ]
    if "sessions" in h:
        ss = h["sessions"]
        out += ["", f"Held-out sessions ({ss['count']}):", ""]
        for name in ("base", "best"):
            out.append(f"{name}:")
            out.append("")
            out += _mode_table(ss[name], ["sessions"], tuned)
            out.append("")
    elif h.get("sessions_note"):
        out += ["", h["sessions_note"]]
    return out
