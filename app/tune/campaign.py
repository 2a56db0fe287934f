"""A tuning campaign (`dsteleop tune`, docs/tune.md): the search, its widening rounds, the
held-out check of the best configuration and the outputs, given a parsed `Plan` and a cluster
to run the trials on; app/cli/tune.py is only the command's parsing and shell.

    settings   a new study's settings are the given options over `DEFAULTS`; a resumed one's
               are the stored study's (a given option must equal them); both are checked
               whole (`new_settings`, `resumed_settings`) before a cluster starts
    round 0    the first campaign: `trials` (or K per searched parameter) asked of Optuna and
               run as tasks (app/tune/driver.py), stored in DIR
    widening   while the round's best value sits on a widenable edge of its range, the range is
               widened there (app/tune/edges.py) and a fresh campaign with the same budget runs
               in DIR/widen-K, up to `widen_edges` rounds; the last round is the result
    hold-out   the best configuration and the base on held-out trajectories (another seed)
               and sessions, paired (app/tune/holdout.py)
    outputs    DIR/trials.csv (each round's too), best.json, sensitivity.png (heatmap.png for a
               two-parameter grid), summary.json and summary.md; `brief` is the command's JSON
               line
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from dsteleop.app.jsonable import jsonable
from dsteleop.app.study.planar import OPERATOR_FIELDS
from dsteleop.app.tasks.executor import Cluster
from dsteleop.app.tasks.progress import Progress
from dsteleop.app.tune import driver, figures, report
from dsteleop.app.tune.driver import TrialRecord, TuneSettings
from dsteleop.app.tune.edges import Edge, widen
from dsteleop.app.tune.holdout import HoldoutError
from dsteleop.app.tune.report import SUMMARY_SCHEMA, power
from dsteleop.app.tune.space import default_space, out_of_domain
from dsteleop.app.tune.trial import StudyBatch, describe_world, pack_session
from dsteleop.arbitration import ArbitrationConfig
from dsteleop.errors import ConfigError, InputError

if TYPE_CHECKING:
    import optuna

log = logging.getLogger("dsteleop.tune")

DEFAULTS: dict[str, Any] = {
    "objective": "study",
    "metric": "agreement",
    "constrained": True,
    "mode": "DS",
    "sampler": "tpe",
    "seed": 0,
    "grid_points": 5,
    "trajectories": 400,
    "study_seed": 0,
}


@dataclass(frozen=True)
class Plan:
    """What a campaign is asked to do (the `tune` command's options, parsed and checked).

    Attributes:
        given: the options that define the search, as given (in the form of
            `TuneSettings.to_dict`); the rest take `DEFAULTS`, or with `resume` the stored
            study's values (which the given ones must equal).
        trials: a campaign's number of trials in all (with `resume`, including earlier
            ones); None: `trials_per_param` times the searched parameters.
        trials_per_param: K of `--trials-per-param` (None: `trials` is fixed).
        widen_edges: widening rounds after the first campaign (app/tune/edges.py; 0: none).
        resume: continue the study stored in the output folder.
        sessions_via: how sessions reach the workers (None: paths on a local cluster, the
            object store on another).
        holdout_trajectories: held-out study trajectories (0: no held-out evaluation).
        holdout_seed: their seed (None: the tuning batch's seed + 1).
        holdout_sessions: held-out session folders.
        figures: draw the PNG figures.
    """

    given: dict[str, Any]
    trials: int | None
    trials_per_param: int | None = None
    widen_edges: int = 2
    resume: bool = False
    sessions_via: Literal["path", "store"] | None = None
    holdout_trajectories: int = 1000
    holdout_seed: int | None = None
    holdout_sessions: tuple[str, ...] = field(default_factory=tuple)
    figures: bool = True


def new_settings(given: dict[str, Any]) -> TuneSettings:
    """The settings of a new study: the given options over the defaults."""
    d: dict[str, Any] = {
        "schema": driver.SETTINGS_SCHEMA,
        **DEFAULTS,
        "sessions": [],
        "base": ArbitrationConfig().to_dict(),
        **given,
    }
    if "space" not in given:
        d["space"] = list(default_space(d["mode"]))
    if d["objective"] == "sessions":
        for k in ("trajectories", "study_seed"):
            if k in given:
                raise ConfigError(f"--{k.replace('_', '-')}: --objective sessions runs no study")
            d[k] = None
    return _check(TuneSettings.from_dict(d))


def resumed_settings(stored: TuneSettings, given: dict[str, Any]) -> TuneSettings:
    """The stored study's settings; a given option that differs is a ConfigError."""
    current = stored.to_dict()
    for k, v in given.items():
        if current.get(k) != v:
            raise ConfigError(
                f"--resume: the study was made with {k} = {json.dumps(current.get(k))}, not "
                f"{json.dumps(v)} (leave it out to continue the same study)"
            )
    return _check(stored)


def _check(settings: TuneSettings) -> TuneSettings:
    """Checks that need the whole settings."""
    if settings.batch is not None:
        if settings.batch.trajectories < 1:
            raise ConfigError(f"--trajectories must be >= 1, got {settings.batch.trajectories}")
        if settings.batch.seed < 0:
            raise ConfigError(f"--study-seed must be >= 0, got {settings.batch.seed}")
        for d in settings.space:
            if d.name in OPERATOR_FIELDS:
                raise ConfigError(
                    f"--space {d.name}: the study's simulated person moves at just under the "
                    "robot's velocity limits (docs/operator.md), so searching them would tune "
                    "the person too; search them on recorded sessions (--objective sessions)"
                )
    return settings


def run(
    plan: Plan,
    out: Path,
    open_cluster: Callable[[], Cluster],
    show_progress: bool,
    t_start: float,
) -> dict[str, Any]:
    """Run the campaign `plan` in the folder `out` and write its outputs (module docstring);
    returns summary.json's object.

    Args:
        plan: what to do.
        out: the output folder (it holds the studies).
        open_cluster: opens the cluster the trials run on; called once every check passed.
        show_progress: draw progress bars on stderr.
        t_start: when the command started (`time.monotonic`), for the timing.

    Raises:
        ConfigError, InputError: bad settings, a study in `out` without `resume` (or none
            with it), a cluster that cannot start (one line each), before any trial runs.
    """
    storage = out / driver.STORAGE_FILE
    if plan.resume:
        if not storage.exists():
            raise InputError(f"--resume: no tuning study in {out} (no {driver.STORAGE_FILE})")
        study = driver.open_study(out, None, resume=True)
        settings = resumed_settings(driver.stored_settings(study), plan.given)
    else:
        if storage.exists():
            raise InputError(
                f"{out} holds a tuning study already: --resume continues it, or choose "
                "another --out"
            )
        settings = new_settings(plan.given)
        study = None
    holdout_seed = _holdout_seed(plan, settings)
    budget = _budget(plan, settings)
    for line in out_of_domain(settings.space, settings.base):
        log.warning("tune: %s; trials that draw it will fail", line)

    t0 = time.monotonic()
    executor = open_cluster()
    cluster_start_s = time.monotonic() - t0
    try:
        via = plan.sessions_via or ("path" if executor.local else "store")
        rounds: list[Round] = []
        current = settings
        for k in range(plan.widen_edges + 1):
            if k == 0:
                study = study or driver.open_study(out, settings, resume=False)
            else:
                study = _round_study(round_dir(out, k), current, plan.resume)
            rnd = _campaign(
                plan, out, k, current, study, executor, budget["trials"], via, show_progress
            )
            rounds.append(rnd)
            if rnd.best is None:
                break
            widened, rnd.edges = widen(current.space, rnd.best.params, current.base)
            if k == plan.widen_edges or widened == current.space:
                break
            log.info(
                "tune: the best of round %d is on an edge (%s); round %d searches %s",
                k, "; ".join(e.describe() for e in rnd.edges), k + 1,
                " ".join(d.spec for d in widened),
            )  # fmt: skip
            current = dataclasses.replace(current, space=widened)
        final = rounds[-1]
        # Edges of the final best that could have been widened were not: say why.
        final.edges = [
            e.with_status("off" if plan.widen_edges == 0 else "rounds") if e.widenable else e
            for e in final.edges
        ]
        recs, best = final.recs, final.best
        t2 = time.monotonic()
        try:
            holdout = _holdout(
                plan, final.settings, executor, best, holdout_seed, via, show_progress
            )
        except HoldoutError as exc:  # the search's results stand; say why there is no check
            log.warning("tune: %s", exc)
            holdout = {"error": str(exc)}
        holdout_s = time.monotonic() - t2
        cluster = executor.describe()
    finally:
        executor.close()

    files = _write(plan, final.settings, recs, best, holdout, out, rounds)
    n_new = sum(len(r.new) for r in rounds)
    trials_wall_s = sum(r.wall_s for r in rounds)
    timing = {
        "wall_s": time.monotonic() - t_start,
        "cluster_start_s": cluster_start_s,
        "trials_run": n_new,
        "trials_wall_s": trials_wall_s,
        "trials_per_minute": 60.0 * n_new / trials_wall_s if n_new and trials_wall_s > 0 else None,
        "holdout_s": holdout_s,
    }
    summary = _summary(plan, final.settings, recs, best, holdout, cluster, timing, files, out)
    summary["budget"] = budget
    summary["rounds"] = [r.to_dict(out) for r in rounds]
    summary["edges"] = [e.to_dict() for e in final.edges]
    summary["widen_edges"] = plan.widen_edges
    (out / "summary.json").write_text(json.dumps(jsonable(summary), indent=2) + "\n")
    (out / "summary.md").write_text(report.markdown(summary))
    return summary


def failure(summary: dict[str, Any]) -> str | None:
    """One line when trials ran and every one failed (the command's error), else None."""
    t = summary["trials"]
    if not t["finished"] or t["complete"]:
        return None
    first = next((e for e in t["errors"] if e), "")
    return f"every trial failed, the first with {first} (trials.csv has each)"


def round_dir(out: Path, k: int) -> Path:
    """Where campaign `k` is stored: DIR for the first, DIR/widen-K for widening round K."""
    return out if k == 0 else out / f"widen-{k}"


@dataclass
class Round:
    """One campaign: a fresh study over one search space with the whole budget.

    Attributes:
        number: 0 for the first campaign, K for widening round K.
        settings: its settings (the first's with the widened space).
        recs: its finished trials.
        best: its best trial (None: none feasible).
        new: the trials this run ran.
        wall_s: their wall time [s].
        edges: the best's edges (app/tune/edges.py).
    """

    number: int
    settings: TuneSettings
    recs: list[TrialRecord]
    best: TrialRecord | None
    new: list[TrialRecord]
    wall_s: float
    edges: list[Edge] = field(default_factory=list)

    def to_dict(self, out: Path) -> dict[str, Any]:
        return {
            "round": self.number,
            "folder": str(round_dir(out, self.number)),
            "space": [d.spec for d in self.settings.space],
            "trials": len(self.recs),
            "complete": sum(r.state == "COMPLETE" for r in self.recs),
            "best": None
            if self.best is None
            else {"number": self.best.number, "value": self.best.value, "params": self.best.params},
            "edges": [e.to_dict() for e in self.edges],
        }


def _budget(plan: Plan, settings: TuneSettings) -> dict[str, Any]:
    """A campaign's trials and the rule that gave them (every widening round has the same)."""
    n = len(settings.space)
    if plan.trials_per_param is not None:
        k = plan.trials_per_param
        rule = f"--trials-per-param {k}: {k} trials per searched parameter x {n} = {k * n}"
        return {"rule": rule, "per_param": k, "params": n, "trials": k * n}
    rule = f"--trials {plan.trials}: a fixed number, whatever the {n} searched parameter(s)"
    return {"rule": rule, "per_param": None, "params": n, "trials": plan.trials}


def _round_study(folder: Path, settings: TuneSettings, resume: bool) -> optuna.Study:
    """The study of a widening round: a new one, or with `resume` the stored one, which must
    search the space the previous round's best widens to now."""
    if not (folder / driver.STORAGE_FILE).exists():
        folder.mkdir(exist_ok=True)
        return driver.open_study(folder, settings, resume=False)
    if not resume:
        raise InputError(f"{folder} holds a tuning study already: choose another --out")
    study = driver.open_study(folder, None, resume=True)
    stored = driver.stored_settings(study)
    if stored.to_dict() != settings.to_dict():
        raise ConfigError(
            f"--resume: {folder.name} searched {' '.join(d.spec for d in stored.space)}, but the "
            f"previous round's best now widens the space to "
            f"{' '.join(d.spec for d in settings.space)}; choose another --out"
        )
    return study


def _campaign(
    plan: Plan,
    out: Path,
    number: int,
    settings: TuneSettings,
    study: optuna.Study,
    executor: Cluster,
    trials: int,
    via: Literal["path", "store"],
    show: bool,
) -> Round:
    """Run a campaign's remaining trials (of `trials` in all) and collect its results."""
    requeued = driver.requeue_interrupted(study) if plan.resume else 0
    n_before = driver.counted(study)
    limit = trials
    if settings.sampler == "grid":
        limit = min(limit, settings.grid_size)
    todo = max(0, limit - n_before)
    log.info(
        "tune: %s%s; %d trial(s) to run (%d done before%s), sampler %s, %s with %d CPUs, out %s",
        settings.objective.statement(),
        f" (widening round {number}: {' '.join(d.spec for d in settings.space)})"
        if number else "",
        todo, n_before,
        f", {requeued} interrupted asked again" if requeued else "",
        settings.sampler, _where(executor), executor.capacity, round_dir(out, number),
    )  # fmt: skip
    best_so_far = driver.best_of(driver.records(study, settings.space), settings.objective)
    failed = 0

    def on_trial(rec: TrialRecord) -> None:
        nonlocal best_so_far, failed
        failed += rec.state == "FAIL"
        if driver.best_of([r for r in (best_so_far, rec) if r], settings.objective) is rec:
            best_so_far = rec
        parts = (
            [] if best_so_far is None else [f"best {best_so_far.value:.4g} (#{best_so_far.number})"]
        )
        if failed:
            parts.append(f"{failed} failed")
        bar.advance(1, ", ".join(parts))

    t1 = time.monotonic()
    label = "tune" if number == 0 else f"widen {number}"
    with Progress(todo, sys.stderr, show, label, "trials") as bar:
        new = driver.run_trials(
            study, settings, executor, todo, sessions_via=via, on_trial=on_trial
        )
    wall_s = time.monotonic() - t1
    recs = driver.records(study, settings.space)
    return Round(number, settings, recs, driver.best_of(recs, settings.objective), new, wall_s)


def _where(executor: Cluster) -> str:
    """Where the trials run, for the log: a local Ray cluster or the cluster's address."""
    cluster = str(executor.describe()["cluster"])
    return "a local Ray cluster" if cluster == "local" else cluster


def _holdout_seed(plan: Plan, settings: TuneSettings) -> int:
    tuning = settings.batch.seed if settings.batch is not None else DEFAULTS["study_seed"]
    seed = plan.holdout_seed if plan.holdout_seed is not None else tuning + 1
    if seed < 0:
        raise ConfigError(f"--holdout-seed must be >= 0, got {seed}")
    if settings.batch is not None and seed == settings.batch.seed:
        raise ConfigError(
            f"--holdout-seed {seed} is the tuning trajectories' seed: held-out trajectories "
            "need another"
        )
    return seed


def _holdout(
    plan: Plan,
    settings: TuneSettings,
    executor: Cluster,
    best: TrialRecord | None,
    seed: int,
    via: Literal["path", "store"],
    show: bool,
) -> dict[str, Any] | None:
    """The held-out comparison of the best configuration with the base (None without a best
    configuration or with nothing held out)."""
    from dsteleop.app.tune import holdout  # here: elsewhere `holdout` names a result

    if best is None or (plan.holdout_trajectories == 0 and not plan.holdout_sessions):
        return None
    configs = holdout.settings_configs(settings, best.params)
    out: dict[str, Any] = {}
    n_tasks = 0
    batch = None
    if plan.holdout_trajectories > 0:
        batch = StudyBatch(plan.holdout_trajectories, seed, settings.mode, settings.world)
        n_tasks += holdout.tasks(batch, len(configs), executor.capacity)
    n_tasks += 4 * len(plan.holdout_sessions)
    with Progress(n_tasks, sys.stderr, show, "held-out", "tasks") as bar:
        if batch is not None:
            res = holdout.study_holdout(executor, batch, configs, on_task=bar.advance)
            study = holdout.compare(res, mode=settings.mode)
            study["seed"] = seed
            study["tuning_seed"] = None if settings.batch is None else settings.batch.seed
            out["study"] = study
        if plan.holdout_sessions:
            refs = [
                p if via == "path" else executor.share(pack_session(Path(p)))
                for p in plan.holdout_sessions
            ]
            by_config = holdout.sessions_holdout(
                executor, refs, configs, on_task=bar.advance, mode=settings.mode
            )
            out["sessions"] = {"count": len(plan.holdout_sessions), **by_config}
    if "sessions" in settings.objective.sources and not plan.holdout_sessions:
        out["sessions_note"] = (
            "The sessions were not held out (no --holdout-sessions): the sessions' numbers of "
            "the best trial above are in-sample."
        )
    return out


def _write(
    plan: Plan,
    settings: TuneSettings,
    recs: list[TrialRecord],
    best: TrialRecord | None,
    holdout: dict[str, Any] | None,
    out: Path,
    rounds: list[Round],
) -> list[str]:
    """The final round's trials.csv, best.json and figures in DIR; with widening rounds,
    each round's trials too (the first's in DIR/trials-round-0.csv, round K's in
    DIR/widen-K/trials.csv)."""

    files = ["trials.csv"]
    report.write_trials_csv(settings, recs, out / "trials.csv")
    if len(rounds) > 1:
        for r in rounds:
            name = "trials-round-0.csv" if r.number == 0 else f"widen-{r.number}/trials.csv"
            report.write_trials_csv(r.settings, r.recs, out / name)
            files.append(name)
    best_path = out / "best.json"
    if best is not None:
        best_path.write_text(
            json.dumps(jsonable(report.best_json(settings, best, holdout, out)), indent=2) + "\n"
        )
        files.append("best.json")
    elif best_path.exists():
        best_path.unlink()  # a resumed study whose best no longer stands (never happens: kept)
    if plan.figures and any(r.state == "COMPLETE" for r in recs):
        files.append(figures.write_sensitivity(settings, recs, best, out))
        heat = figures.write_heatmap(settings, recs, out)
        if heat:
            files.append(heat)
    files += ["summary.md", "summary.json", "study.journal"]
    files += [f"widen-{r.number}/study.journal" for r in rounds if r.number]
    return files


def _summary(
    plan: Plan,
    settings: TuneSettings,
    recs: list[TrialRecord],
    best: TrialRecord | None,
    holdout: dict[str, Any] | None,
    cluster: dict[str, Any],
    timing: dict[str, Any],
    files: list[str],
    out: Path,
) -> dict[str, Any]:
    """summary.json's object, but for what `run` adds (budget, rounds, edges)."""
    errors: dict[str, list[int]] = defaultdict(list)
    for r in recs:
        if r.state == "FAIL":
            errors[r.error].append(r.number)
    return {
        "schema": SUMMARY_SCHEMA,
        "out": str(out),
        "settings": settings.to_dict(),
        "base_is_default": settings.base == ArbitrationConfig(),
        "world": {"overrides": dict(settings.world), "statement": describe_world(settings.world)},
        "objective": {**settings.objective.to_dict(), "sources": list(settings.objective.sources)},
        "trials": {
            "finished": len(recs),
            "complete": sum(r.state == "COMPLETE" for r in recs),
            "failed": sum(r.state == "FAIL" for r in recs),
            "feasible": sum(r.feasible for r in recs),
            "errors": dict(errors),
            "requested": _budget(plan, settings)["trials"],
            "grid_size": settings.grid_size if settings.sampler == "grid" else None,
        },
        "best": None
        if best is None
        else {
            "number": best.number,
            "value": best.value,
            "params": best.params,
            "metrics": best.metrics,
            "arbitration": settings.arbitration(best.params),
        },
        "holdout": holdout,
        "power": power(settings, recs),
        "cluster": cluster,
        "timing": timing,
        "files": files,
    }


def brief(summary: dict[str, Any]) -> dict[str, Any]:
    """The command's JSON line on stdout (`jsonable` it)."""
    best = summary["best"]
    h = (summary.get("holdout") or {}).get("study")
    gain = None
    if h:
        g = h[f"gain_{summary['settings'].get('mode', 'DS')}"]
        gain = {
            "trajectories": h["trajectories"],
            "seed": h["seed"],
            **{k: {"mean": g[k]["mean"], "ci95": g[k]["ci95"]} for k in g},
        }
    return {
        "out": summary["out"],
        "objective": summary["objective"]["statement"],
        "trials": {k: summary["trials"][k] for k in ("finished", "complete", "failed")},
        "world": summary["world"]["statement"],
        "budget": summary["budget"]["rule"],
        "rounds": len(summary["rounds"]),
        "edges": [
            {k: e[k] for k in ("name", "side", "value", "end", "status", "new_end")}
            for e in summary["edges"]
        ],
        "best": None
        if best is None
        else {"number": best["number"], "value": best["value"], "params": best["params"]},
        f"holdout_gain_{summary['settings'].get('mode', 'DS')}_over_base": gain,
        "cluster": summary["cluster"],
        "timing": summary["timing"],
        "files": summary["files"],
    }
