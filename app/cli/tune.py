"""`dsteleop tune`: hyper-parameter studies of the arbitration, trials as Ray tasks.

    dsteleop tune --objective study|sessions|both --trials N|--trials-per-param K --out DIR
                  [--mode M] [--space NAME=SPEC ...] [--widen-edges N]
                  [--metric agreement|cosine_distance|time_s|success]
                  [--no-constraint] [--sampler tpe|grid|random] [--seed K] [--grid-points K]
                  [--trajectories N] [--study-seed S] [world options of `dsteleop sim`]
                  [--sessions PATH ...]
                  [--sessions-via path|store] [--holdout-trajectories M] [--holdout-seed S]
                  [--holdout-sessions PATH ...] [--address ray://HOST:PORT|auto|HOST:PORT]
                  [--workers N] [--config FILE.json] [--param NAME=VALUE ...] [--resume]

`--mode M` tunes mode M (default DS; any registered mode but S, the reference every trial is
paired with) over its own default space (stated next to the mode, `arbitration/modes/`)
unless `--space` gives one. `--trials-per-param K` makes the budget K trials per searched
parameter (a fair comparison of modes gives each the same K); the world options are
`dsteleop sim`'s (app/cli/world_options.py), for the tuning and held-out trajectories
alike. A best value on an edge of its range widens the range and runs the campaign again,
up to `--widen-edges N` times (app/tune/edges.py); every edge of the final best is reported.

Optuna asks for configurations, Ray runs their trials (a local cluster on this machine unless
`--address` names one), results are told back as they arrive; DIR gets trials.csv, best.json,
sensitivity.png (and heatmap.png for a two-parameter grid), summary.md and summary.json, and
stdout one JSON line. `--config`/`--param` give the base configuration (default: the
defaults) that the searched parameters vary and that the best is compared with on held-out
data. docs/tune.md describes it all, and how to run it on a cluster.

Everything is checked before a cluster starts: a bad argument, an unknown parameter, a
malformed range, a missing session, an unreachable address is one line and exit code 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from dsteleop.app.cli.options import arbitration_config
from dsteleop.app.cli.world_options import add_world_arguments, world_overrides
from dsteleop.app.outpaths import created_dir, output_dir
from dsteleop.app.tasks.progress import Progress
from dsteleop.errors import ConfigError, InputError

if TYPE_CHECKING:  # the command imports them when it runs (an instant --help)
    import optuna

    from dsteleop.app.tasks.cluster import RayExecutor
    from dsteleop.app.tune.driver import TrialRecord, TuneSettings
    from dsteleop.app.tune.edges import Edge

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
class TuneCommand:
    """The `tune` command's settings.

    Attributes:
        given: the options that define the search, as given on the command line (in the form
            of `TuneSettings.to_dict`); the rest take their defaults, or with `resume` the
            stored study's values (which the given ones must equal).
        trials: a campaign's number of trials in all (with `resume`, including earlier
            ones); None: `trials_per_param` times the searched parameters.
        trials_per_param: K of `--trials-per-param` (None: `trials` is fixed).
        widen_edges: widening rounds after the first campaign (app/tune/edges.py; 0: none).
        out: the output folder (holds the study's storage).
        resume: continue the study stored in `out`.
        address: the Ray cluster (None: a local one).
        workers: CPUs of a local cluster (None: every core).
        sessions_via: how sessions reach the workers (None: paths on a local cluster, the
            object store on another).
        holdout_trajectories: held-out study trajectories (0: no held-out evaluation).
        holdout_seed: their seed (None: the tuning batch's seed + 1).
        holdout_sessions: held-out session folders.
        figures: draw the PNG figures.
        progress: draw the progress bar (None: on a terminal).
    """

    given: dict[str, Any]
    trials: int | None
    out: Path
    trials_per_param: int | None = None
    widen_edges: int = 2
    resume: bool = False
    address: str | None = None
    workers: int | None = None
    sessions_via: Literal["path", "store"] | None = None
    holdout_trajectories: int = 1000
    holdout_seed: int | None = None
    holdout_sessions: tuple[str, ...] = field(default_factory=tuple)
    figures: bool = True
    progress: bool | None = None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from dsteleop.app.tune.space import SPACE_GRAMMAR
    from dsteleop.arbitration import registered

    a = parser.add_argument
    a("--objective", default=None, help="study (default), sessions or both")
    a(
        "--mode",
        default=None,
        help="the mode tuned, paired with S in every trial: "
        f"{', '.join(m.value for m in registered() if m.value != 'S')} (default DS)",
    )
    budget = parser.add_mutually_exclusive_group()
    budget.add_argument(
        "--trials", type=int, default=None, metavar="N", help="trials in all (default 40)"
    )
    budget.add_argument(
        "--trials-per-param",
        type=int,
        default=None,
        metavar="K",
        help="trials = K x the searched parameters (a fair comparison gives every mode the "
        "same K; docs/tune.md)",
    )
    a(
        "--widen-edges",
        type=int,
        default=2,
        metavar="N",
        help="widening rounds: a best value on its range's edge widens the range there and "
        "the campaign is run again, up to N times (default 2; 0: off; docs/tune.md)",
    )
    a("--out", required=True, type=output_dir, metavar="DIR", help="output folder (the study's)")
    a(
        "--space",
        action="append",
        default=None,
        metavar="NAME=SPEC",
        help=f"a searched parameter, repeatable: {SPACE_GRAMMAR} "
        "(default: the mode's own, e.g. DS: "
        f"{' '.join(registered()[0].spec.space)})",
    )
    a(
        "--metric",
        default=None,
        help="the mode's metric to optimise: agreement (default), cosine_distance, time_s, success",
    )
    a(
        "--no-constraint",
        dest="constrained",
        action="store_const",
        const=False,
        default=None,
        help="do not require the mode to succeed at least as often as S",
    )
    a("--sampler", default=None, help="tpe (default), grid or random")
    a("--seed", type=int, default=None, help="the sampler's seed (default 0)")
    a("--grid-points", type=int, default=None, metavar="K", help="grid values per range (5)")
    a(
        "--trajectories",
        type=int,
        default=None,
        metavar="N",
        help="the study's tuning trajectories per trial (default 400)",
    )
    a("--study-seed", type=int, default=None, metavar="S", help="their seed (default 0)")
    add_world_arguments(parser)
    a("--sessions", nargs="+", default=None, metavar="PATH", help="sessions (or folders) to replay")
    a(
        "--sessions-via",
        choices=("path", "store"),
        default=None,
        help="how sessions reach the workers: their paths (default on a local cluster) or "
        "Ray's object store (default with --address)",
    )
    a(
        "--holdout-trajectories",
        type=int,
        default=1000,
        metavar="M",
        help="held-out study trajectories for the final comparison (default 1000; 0: none)",
    )
    a("--holdout-seed", type=int, default=None, metavar="S", help="their seed (default: S + 1)")
    a("--holdout-sessions", nargs="+", default=(), metavar="PATH", help="held-out sessions")
    a(
        "--address",
        default=None,
        help="a Ray cluster: ray://HOST:PORT, HOST:PORT or auto (default: start a local one)",
    )
    a("--workers", type=int, default=None, metavar="N", help="CPUs of the local cluster (all)")
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="FILE.json",
        help="the base configuration (default: the defaults)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a fixed base parameter (repeatable; over --config)",
    )
    a("--resume", action="store_true", help="continue the study stored in DIR")
    a("--no-figures", action="store_true", help="skip the PNG figures")
    bar = parser.add_mutually_exclusive_group()
    bar.add_argument("--progress", dest="progress", action="store_true", default=None)
    bar.add_argument("--no-progress", dest="progress", action="store_false")


def _sessions(items: list[str] | tuple[str, ...], option: str) -> list[str]:
    """Session folders (a folder of sessions counts for each, as in `replay`), absolute,
    each readable."""
    from dsteleop.app.session.reader import read_session, sessions_in

    out: list[str] = []
    for s in items:
        p = Path(s)
        if not p.exists():
            raise InputError(f"{option}: not found: {p}")
        subs = sessions_in(p) if p.is_dir() else [p]
        if not subs:
            raise InputError(f"{option}: {p} is not a session and holds none")
        out.extend(str(q.resolve()) for q in subs)
    for p_s in out:
        read_session(Path(p_s))  # a missing or corrupt session: one line, now
    if len(set(out)) != len(out):
        raise ConfigError(f"{option}: a session is named twice")
    return out


def command(args: argparse.Namespace) -> TuneCommand:
    """The command's settings; bad values raise ConfigError or InputError with one line."""
    from dsteleop.app.tasks.cluster import parse_address
    from dsteleop.app.tune.space import parse_space

    given: dict[str, Any] = {}
    if args.mode is not None:
        from dsteleop.arbitration import Mode

        given["mode"] = Mode.parse(args.mode).value
    for name in ("objective", "metric", "constrained", "sampler", "seed", "grid_points"):
        if getattr(args, name) is not None:
            given[name] = getattr(args, name)
    if args.trajectories is not None:
        given["trajectories"] = args.trajectories
    if args.study_seed is not None:
        given["study_seed"] = args.study_seed
    overrides = world_overrides(args)
    if overrides:
        from dsteleop.app.study.planar import SimConfig
        from dsteleop.app.tune.trial import world_of

        SimConfig(trajectories=1, **overrides)  # a bad world: one line, now
        given["world"] = dict(world_of(overrides))
    if args.space is not None:
        given["space"] = [d.spec for d in parse_space(args.space, given.get("mode", "DS"))]
    if args.sessions is not None:
        given["sessions"] = _sessions(args.sessions, "--sessions")
    if args.config is not None or args.param:
        base = arbitration_config(args)
        given["base"] = base.to_dict()
    if args.trials is not None and args.trials < 1:
        raise ConfigError(f"--trials must be >= 1, got {args.trials}")
    if args.trials_per_param is not None and args.trials_per_param < 1:
        raise ConfigError(f"--trials-per-param must be >= 1, got {args.trials_per_param}")
    if args.widen_edges < 0:
        raise ConfigError(f"--widen-edges must be >= 0, got {args.widen_edges}")
    if args.holdout_trajectories < 0:
        raise ConfigError(f"--holdout-trajectories must be >= 0, got {args.holdout_trajectories}")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.address is not None:
        raise ConfigError("--workers sizes a local cluster; a cluster at --address has its own")
    parse_address(args.address)
    holdout_sessions = _sessions(args.holdout_sessions, "--holdout-sessions")
    overlap = set(holdout_sessions) & set(given.get("sessions", ()))
    if overlap:
        raise ConfigError(
            f"--holdout-sessions: {Path(sorted(overlap)[0]).name} is also a tuning session"
        )
    return TuneCommand(
        given=given,
        trials=None if args.trials_per_param is not None else int(args.trials or 40),
        out=Path(args.out),
        trials_per_param=args.trials_per_param,
        widen_edges=int(args.widen_edges),
        resume=bool(args.resume),
        address=args.address,
        workers=args.workers,
        sessions_via=args.sessions_via,
        holdout_trajectories=int(args.holdout_trajectories),
        holdout_seed=args.holdout_seed,
        holdout_sessions=tuple(holdout_sessions),
        figures=not args.no_figures,
        progress=args.progress,
    )


def new_settings(given: dict[str, Any]) -> TuneSettings:
    """The settings of a new study: the given options over the defaults."""
    from dsteleop.app.tune.driver import SETTINGS_SCHEMA, TuneSettings
    from dsteleop.app.tune.space import default_space
    from dsteleop.arbitration import ArbitrationConfig

    d: dict[str, Any] = {
        "schema": SETTINGS_SCHEMA,
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
    from dsteleop.app.study.planar import OPERATOR_FIELDS

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


def run(args: argparse.Namespace) -> int:
    t_start = time.monotonic()
    cmd = command(args)
    # A tuning run that fails leaves no empty --out behind (outpaths.created_dir).
    with created_dir(cmd.out) as out:
        return _run(cmd, out, t_start)


def _run(cmd: TuneCommand, out: Path, t_start: float) -> int:
    from dsteleop.app.tasks.cluster import RayExecutor
    from dsteleop.app.tune import driver
    from dsteleop.app.tune.edges import widen
    from dsteleop.app.tune.holdout import HoldoutError
    from dsteleop.app.tune.space import out_of_domain

    storage = out / driver.STORAGE_FILE
    if cmd.resume:
        if not storage.exists():
            raise InputError(f"--resume: no tuning study in {out} (no {driver.STORAGE_FILE})")
        study = driver.open_study(out, None, resume=True)
        settings = resumed_settings(driver.stored_settings(study), cmd.given)
    else:
        if storage.exists():
            raise InputError(
                f"{out} holds a tuning study already: --resume continues it, or choose "
                "another --out"
            )
        settings = new_settings(cmd.given)
        study = None
    holdout_seed = _holdout_seed(cmd, settings)
    budget = _budget(cmd, settings)
    for line in out_of_domain(settings.space, settings.base):
        log.warning("tune: %s; trials that draw it will fail", line)
    show = sys.stderr.isatty() if cmd.progress is None else bool(cmd.progress)

    t0 = time.monotonic()
    executor = RayExecutor(cmd.address, cmd.workers)
    cluster_start_s = time.monotonic() - t0
    try:
        via = cmd.sessions_via or ("path" if executor.local else "store")
        rounds: list[Round] = []
        current = settings
        for k in range(cmd.widen_edges + 1):
            if k == 0:
                study = study or driver.open_study(out, settings, resume=False)
            else:
                study = _round_study(round_dir(out, k), current, cmd.resume)
            rnd = _campaign(cmd, k, current, study, executor, budget["trials"], via, show)
            rounds.append(rnd)
            if rnd.best is None:
                break
            widened, rnd.edges = widen(current.space, rnd.best.params, current.base)
            if k == cmd.widen_edges or widened == current.space:
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
            e.with_status("off" if cmd.widen_edges == 0 else "rounds") if e.widenable else e
            for e in final.edges
        ]
        recs, best = final.recs, final.best
        t2 = time.monotonic()
        try:
            holdout = _holdout(cmd, final.settings, executor, best, holdout_seed, via, show)
        except HoldoutError as exc:  # the search's results stand; say why there is no check
            log.warning("tune: %s", exc)
            holdout = {"error": str(exc)}
        holdout_s = time.monotonic() - t2
        cluster = executor.describe()
    finally:
        executor.close()

    files = _write(cmd, final.settings, recs, best, holdout, out, rounds)
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
    summary = _summary(cmd, final.settings, recs, best, holdout, cluster, timing, files, out)
    summary["budget"] = budget
    summary["rounds"] = [r.to_dict(out) for r in rounds]
    summary["edges"] = [e.to_dict() for e in final.edges]
    summary["widen_edges"] = cmd.widen_edges
    (out / "summary.json").write_text(json.dumps(_json(summary), indent=2) + "\n")
    from dsteleop.app.tune.report import markdown

    (out / "summary.md").write_text(markdown(summary))
    json.dump(_json(_brief(summary)), sys.stdout, separators=(",", ":"))
    sys.stdout.write("\n")
    if recs and not any(r.state == "COMPLETE" for r in recs):
        first = next((r.error for r in recs if r.error), "")
        raise InputError(f"every trial failed, the first with {first} (trials.csv has each)")
    return 0


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


def _budget(cmd: TuneCommand, settings: TuneSettings) -> dict[str, Any]:
    """A campaign's trials and the rule that gave them (every widening round has the same)."""
    n = len(settings.space)
    if cmd.trials_per_param is not None:
        k = cmd.trials_per_param
        rule = f"--trials-per-param {k}: {k} trials per searched parameter x {n} = {k * n}"
        return {"rule": rule, "per_param": k, "params": n, "trials": k * n}
    rule = f"--trials {cmd.trials}: a fixed number, whatever the {n} searched parameter(s)"
    return {"rule": rule, "per_param": None, "params": n, "trials": cmd.trials}


def _round_study(folder: Path, settings: TuneSettings, resume: bool) -> optuna.Study:
    """The study of a widening round: a new one, or with `resume` the stored one, which must
    search the space the previous round's best widens to now."""
    from dsteleop.app.tune import driver

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
    cmd: TuneCommand,
    number: int,
    settings: TuneSettings,
    study: optuna.Study,
    executor: RayExecutor,
    trials: int,
    via: Literal["path", "store"],
    show: bool,
) -> Round:
    """Run a campaign's remaining trials (of `trials` in all) and collect its results."""
    from dsteleop.app.tune import driver

    requeued = driver.requeue_interrupted(study) if cmd.resume else 0
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
        settings.sampler, "a local Ray cluster" if executor.local else cmd.address,
        executor.capacity, round_dir(cmd.out, number),
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


def _holdout_seed(cmd: TuneCommand, settings: TuneSettings) -> int:
    tuning = settings.batch.seed if settings.batch is not None else DEFAULTS["study_seed"]
    seed = cmd.holdout_seed if cmd.holdout_seed is not None else tuning + 1
    if seed < 0:
        raise ConfigError(f"--holdout-seed must be >= 0, got {seed}")
    if settings.batch is not None and seed == settings.batch.seed:
        raise ConfigError(
            f"--holdout-seed {seed} is the tuning trajectories' seed: held-out trajectories "
            "need another"
        )
    return seed


def _holdout(
    cmd: TuneCommand,
    settings: TuneSettings,
    executor: RayExecutor,
    best: TrialRecord | None,
    seed: int,
    via: Literal["path", "store"],
    show: bool,
) -> dict[str, Any] | None:
    """The held-out comparison of the best configuration with the base (None without a best
    configuration or with nothing held out)."""
    from dsteleop.app.tune import holdout
    from dsteleop.app.tune.trial import StudyBatch, pack_session

    if best is None or (cmd.holdout_trajectories == 0 and not cmd.holdout_sessions):
        return None
    configs = holdout.settings_configs(settings, best.params)
    out: dict[str, Any] = {}
    n_tasks = 0
    batch = None
    if cmd.holdout_trajectories > 0:
        batch = StudyBatch(cmd.holdout_trajectories, seed, settings.mode, settings.world)
        n_tasks += holdout.tasks(batch, len(configs), executor.capacity)
    n_tasks += 4 * len(cmd.holdout_sessions)
    with Progress(n_tasks, sys.stderr, show, "held-out", "tasks") as bar:
        if batch is not None:
            res = holdout.study_holdout(executor, batch, configs, on_task=bar.advance)
            study = holdout.compare(res, mode=settings.mode)
            study["seed"] = seed
            study["tuning_seed"] = None if settings.batch is None else settings.batch.seed
            out["study"] = study
        if cmd.holdout_sessions:
            refs = [
                p if via == "path" else executor.share(pack_session(Path(p)))
                for p in cmd.holdout_sessions
            ]
            by_config = holdout.sessions_holdout(
                executor, refs, configs, on_task=bar.advance, mode=settings.mode
            )
            out["sessions"] = {"count": len(cmd.holdout_sessions), **by_config}
    if "sessions" in settings.objective.sources and not cmd.holdout_sessions:
        out["sessions_note"] = (
            "The sessions were not held out (no --holdout-sessions): the sessions' numbers of "
            "the best trial above are in-sample."
        )
    return out


def _write(
    cmd: TuneCommand,
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
    from dsteleop.app.tune import figures, report

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
            json.dumps(_json(report.best_json(settings, best, holdout, out)), indent=2) + "\n"
        )
        files.append("best.json")
    elif best_path.exists():
        best_path.unlink()  # a resumed study whose best no longer stands (never happens: kept)
    if cmd.figures and any(r.state == "COMPLETE" for r in recs):
        files.append(figures.write_sensitivity(settings, recs, best, out))
        heat = figures.write_heatmap(settings, recs, out)
        if heat:
            files.append(heat)
    files += ["summary.md", "summary.json", "study.journal"]
    files += [f"widen-{r.number}/study.journal" for r in rounds if r.number]
    return files


def _summary(
    cmd: TuneCommand,
    settings: TuneSettings,
    recs: list[TrialRecord],
    best: TrialRecord | None,
    holdout: dict[str, Any] | None,
    cluster: dict[str, Any],
    timing: dict[str, Any],
    files: list[str],
    out: Path,
) -> dict[str, Any]:
    from dsteleop.app.tune.report import SUMMARY_SCHEMA, power
    from dsteleop.app.tune.trial import describe_world
    from dsteleop.arbitration import ArbitrationConfig

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
            "requested": _budget(cmd, settings)["trials"],
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


def _brief(summary: dict[str, Any]) -> dict[str, Any]:
    """The JSON line on stdout."""
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


def _json(v: Any) -> Any:
    """JSON-ready: non-finite floats as null, tuples as lists."""
    if isinstance(v, dict):
        return {str(k): _json(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json(x) for x in v]
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if hasattr(v, "item") and callable(v.item):  # numpy scalars
        return _json(v.item())
    return v
