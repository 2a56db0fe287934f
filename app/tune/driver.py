"""The tuning driver: Optuna asks for configurations, an executor runs their trials, Optuna is
told the results as they arrive.

    ask     up to `executor.capacity` trials at once (a batch), each a configuration drawn by
            the sampler over the search space (app/tune/space.py)
    run     each trial as tasks on the executor (app/tune/trial.py: one for the study batch,
            one per session and mode), so a cluster runs them wherever it has a core
    tell    when every task of a trial is back: its metrics, its objective value and its
            constraint (app/tune/objective.py); a task that raised fails the trial, which is
            recorded as failed (its error kept) while the study goes on

The executor is the only seam to a cluster (`app.tasks.executor.Executor`): `LocalExecutor`
runs tasks in this process (the trial function's throughput alone), `app.tasks.cluster`'s
`RayExecutor` runs them as Ray tasks; nothing here imports Ray.

The study lives in DIR (`study.journal`, Optuna's journal storage, with the settings that
define the search in the study's attributes), so `--resume` continues it: trials that were
running when the driver stopped are marked failed (`interrupted`) and asked again with the same
configuration. Samplers are seeded: with the grid and random samplers the same seed gives the
same sequence of configurations whatever the timing of the results (a random sampler resumed
after n trials is reseeded with (seed, n), so it does not repeat the first ones); TPE's choices
depend on the results that have arrived when it is asked, so its sequence depends on timing
when several trials run at once.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from dsteleop.app.jsonable import finite
from dsteleop.app.tasks.executor import Executor, TaskError
from dsteleop.app.tune.objective import Objective
from dsteleop.app.tune.space import Dimension, Value, as_values, parse_space
from dsteleop.app.tune.trial import (
    SessionRef,
    StudyBatch,
    World,
    pack_session,
    paired,
    session_task,
    sessions_metrics,
    study_task,
)
from dsteleop.arbitration import ArbitrationConfig
from dsteleop.errors import ConfigError, InputError

if TYPE_CHECKING:
    import optuna

Sampler = Literal["tpe", "grid", "random"]
SAMPLERS: tuple[str, ...] = ("tpe", "grid", "random")
STUDY_NAME = "dsteleop-tune"
STORAGE_FILE = "study.journal"
SETTINGS_SCHEMA = "dsteleop.tune_settings/1"


@dataclass(frozen=True)
class TuneSettings:
    """What defines a tuning study (stored with it; `--resume` continues only the same).

    Attributes:
        objective: what is optimised.
        space: the searched hyper-parameters.
        sampler: tpe, grid or random.
        seed: the sampler's seed.
        grid_points: values per range in a grid search.
        batch: the study's tuning trajectories (None: the objective has no study).
        sessions: the replayed sessions' folders (absolute paths).
        base: the configuration the searched parameters replace fields of (the defaults,
            unless `--config`/`--param` say otherwise); the held-out comparison's baseline.
        world: the study's world (`StudyBatch.world`: the tuning batch's and the held-out
            trajectories'; empty: the default world).
    """

    objective: Objective
    space: tuple[Dimension, ...]
    sampler: Sampler = "tpe"
    seed: int = 0
    grid_points: int = 5
    batch: StudyBatch | None = None
    sessions: tuple[str, ...] = ()
    base: ArbitrationConfig = field(default_factory=ArbitrationConfig)
    world: World = ()

    def __post_init__(self) -> None:
        if self.sampler not in SAMPLERS:
            raise ConfigError(
                f"unknown sampler {self.sampler!r} (choose from {', '.join(SAMPLERS)})"
            )
        if self.seed < 0:
            raise ConfigError(f"--seed must be >= 0, got {self.seed}")
        if self.grid_points < 2:
            raise ConfigError(f"--grid-points must be >= 2, got {self.grid_points}")
        if ("study" in self.objective.sources) != (self.batch is not None):
            raise ConfigError("the study's tuning batch is needed exactly when it is an objective")
        if "sessions" in self.objective.sources and not self.sessions:
            raise ConfigError(f"--objective {self.objective.kind} needs --sessions PATH ...")
        if "sessions" not in self.objective.sources and self.sessions:
            raise ConfigError(
                f"--sessions given but --objective {self.objective.kind} does not replay them"
            )
        if self.batch is not None and self.batch.mode != self.objective.mode:
            raise ConfigError("the study's tuning batch is of another mode than the objective's")
        if self.batch is not None and self.batch.world != self.world:
            raise ConfigError("the study's tuning batch is of another world than the settings'")

    @property
    def mode(self) -> str:
        """The tuned mode (paired with S in every trial)."""
        return self.objective.mode

    @property
    def grid_size(self) -> int:
        return int(np.prod([len(d.grid(self.grid_points)) for d in self.space]))

    def arbitration(self, params: Mapping[str, Value]) -> dict[str, Any]:
        """The configuration of a trial: the base with the trial's parameters (not checked
        here: an invalid value fails in the trial)."""
        return {**self.base.to_dict(), **params}

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": SETTINGS_SCHEMA,
            "objective": self.objective.kind,
            "metric": self.objective.metric,
            "constrained": self.objective.constrained,
            "mode": self.objective.mode,
            "space": [d.spec for d in self.space],
            "sampler": self.sampler,
            "seed": self.seed,
            "grid_points": self.grid_points,
            "trajectories": None if self.batch is None else self.batch.trajectories,
            "study_seed": None if self.batch is None else self.batch.seed,
            "sessions": list(self.sessions),
            "base": self.base.to_dict(),
            "world": dict(self.world),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TuneSettings:
        if d.get("schema") != SETTINGS_SCHEMA:
            raise InputError(f"a tuning study of schema {d.get('schema')!r}, not {SETTINGS_SCHEMA}")
        batch = None
        mode = str(d.get("mode", "DS"))  # studies made before modes were plug-ins tuned DS
        world: World = tuple(sorted(dict(d.get("world") or {}).items()))  # none: the default
        if d.get("trajectories") is not None:
            batch = StudyBatch(int(d["trajectories"]), int(d["study_seed"]), mode, world)
        return cls(
            objective=Objective(d["objective"], d["metric"], bool(d["constrained"]), mode),
            space=parse_space(d["space"], mode),
            sampler=d["sampler"],
            seed=int(d["seed"]),
            grid_points=int(d["grid_points"]),
            batch=batch,
            sessions=tuple(d.get("sessions", ())),
            base=ArbitrationConfig.from_dict(d["base"]),
            world=world,
        )


@dataclass(frozen=True)
class TrialRecord:
    """One finished trial.

    Attributes:
        number: Optuna's trial number (0, 1, ... in the order asked).
        state: COMPLETE or FAIL.
        params: the searched parameters' values.
        metrics: `<source>.<MODE>.<metric>` and `<source>.seconds` (app/tune/trial.py).
        value: the objective's value (None when failed).
        constraints: successes(S) - successes(DS) per source (<= 0: feasible).
        seconds: the trial's tasks' own time, summed [s].
        wall_s: from its submission to its last result [s] (includes waiting for a core).
        error: why it failed ("" when it did not).
    """

    number: int
    state: Literal["COMPLETE", "FAIL"]
    params: dict[str, Value]
    metrics: dict[str, float]
    value: float | None
    constraints: tuple[float, ...]
    seconds: float
    wall_s: float
    error: str = ""

    @property
    def feasible(self) -> bool:
        return self.state == "COMPLETE" and all(c <= 0 for c in self.constraints)


def open_study(folder: Path, settings: TuneSettings | None, resume: bool) -> optuna.Study:
    """Create the study in `folder` (resume=False) or load it (resume=True).

    Raises:
        InputError: a study is there already without resume, or none with resume.
    """
    import optuna

    path = folder / STORAGE_FILE
    if not resume and path.exists():
        raise InputError(
            f"{folder} holds a tuning study already: --resume continues it, or choose another --out"
        )
    if resume and not path.exists():
        raise InputError(f"--resume: no tuning study in {folder} (no {STORAGE_FILE})")
    storage = journal_storage(path)
    if resume:
        return optuna.load_study(study_name=STUDY_NAME, storage=storage)
    assert settings is not None
    study = optuna.create_study(
        study_name=STUDY_NAME, storage=storage, direction=settings.objective.direction
    )
    study.set_user_attr("settings", settings.to_dict())
    return study


def memory_study(settings: TuneSettings) -> optuna.Study:
    """A study kept in memory only (benchmarks)."""
    import optuna

    quiet_optuna()
    study = optuna.create_study(study_name=STUDY_NAME, direction=settings.objective.direction)
    study.set_user_attr("settings", settings.to_dict())
    return study


def journal_storage(path: Path) -> optuna.storages.BaseStorage:
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalFileOpenLock

    quiet_optuna()
    backend = JournalFileBackend(str(path), lock_obj=JournalFileOpenLock(str(path)))
    return optuna.storages.JournalStorage(backend)


def quiet_optuna() -> None:
    """Optuna's per-trial log lines and experimental-feature warnings off: the command
    reports for itself."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)


def stored_settings(study: optuna.Study) -> TuneSettings:
    raw = study.user_attrs.get("settings")
    if not isinstance(raw, dict):
        raise InputError("the stored tuning study has no settings")
    return TuneSettings.from_dict(raw)


def sampler_seed(seed: int, n_before: int) -> int:
    """The sampler's seed when `n_before` trials exist: `seed` for a new study, else one
    derived from (seed, n_before)."""
    if n_before == 0:
        return seed
    return int(np.random.SeedSequence([seed, n_before]).generate_state(1)[0])


def make_sampler(settings: TuneSettings, n_before: int) -> optuna.samplers.BaseSampler:
    """The seeded sampler (module docstring)."""
    import optuna

    quiet_optuna()
    if settings.sampler == "grid":
        grid = {d.name: list(d.grid(settings.grid_points)) for d in settings.space}
        # The grid's order is shuffled by the seed and a trial's grid point is its number: the
        # same seed on resume keeps both.
        return _grid_sampler(grid, settings.seed)
    seed = sampler_seed(settings.seed, n_before)
    if settings.sampler == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    # Constraints reach TPE through each trial's `set_constraint` (`run_trials`).
    return optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True)


def _grid_sampler(grid: dict[str, list[Value]], seed: int) -> optuna.samplers.BaseSampler:
    """Optuna's grid sampler without its `study.stop()` after the last grid point, which
    works only inside `study.optimize`; the driver stops at the grid's size itself."""
    import optuna

    class Grid(optuna.samplers.GridSampler):
        def after_trial(self, *args: Any, **kwargs: Any) -> None:
            return None

    return Grid(grid, seed=seed)


def distributions(space: Sequence[Dimension]) -> dict[str, Any]:
    """Optuna's distribution of every dimension."""
    from optuna.distributions import (
        CategoricalDistribution,
        FloatDistribution,
        IntDistribution,
    )

    out: dict[str, Any] = {}
    for d in space:
        if d.kind == "choice":
            out[d.name] = CategoricalDistribution(list(d.choices))
        elif d.kind in ("int", "intlog"):
            out[d.name] = IntDistribution(int(d.low), int(d.high), log=d.kind == "intlog")
        else:
            out[d.name] = FloatDistribution(d.low, d.high, log=d.kind == "log")
    return out


def counted(study: optuna.Study) -> int:
    """Trials that count towards `--trials`: finished, not interrupted."""
    from optuna.trial import TrialState

    return sum(
        1
        for t in study.get_trials(deepcopy=False)
        if t.state == TrialState.COMPLETE
        or (t.state == TrialState.FAIL and not t.user_attrs.get("interrupted"))
    )


def requeue_interrupted(study: optuna.Study) -> int:
    """Trials left running by a driver that stopped: failed as `interrupted`, and their
    configurations asked again first. Returns how many."""
    from optuna.trial import TrialState

    n = 0
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study._storage.set_trial_user_attr(t._trial_id, "interrupted", True)
        study._storage.set_trial_user_attr(t._trial_id, "error", "interrupted (asked again)")
        study.tell(t.number, state=TrialState.FAIL)
        study.enqueue_trial(dict(t.params), skip_if_exists=False)
        n += 1
    return n


def records(study: optuna.Study, space: Sequence[Dimension]) -> list[TrialRecord]:
    """Every finished trial of the study, in number order (interrupted ones left out)."""
    from optuna.trial import TrialState

    out = []
    for t in study.get_trials(deepcopy=False):
        if t.state not in (TrialState.COMPLETE, TrialState.FAIL) or t.user_attrs.get("interrupted"):
            continue
        ua = t.user_attrs
        complete = t.state == TrialState.COMPLETE
        out.append(
            TrialRecord(
                number=t.number,
                state="COMPLETE" if complete else "FAIL",
                params=as_values(t.params, space),
                metrics={
                    k: math.nan if v is None else float(v) for k, v in ua.get("metrics", {}).items()
                },
                value=float(t.value) if complete and t.value is not None else None,
                constraints=tuple(ua.get("constraints", ())),
                seconds=float(ua.get("seconds", 0.0)),
                wall_s=float(ua.get("wall_s", 0.0)),
                error=str(ua.get("error", "")),
            )
        )
    return out


def best_of(recs: Sequence[TrialRecord], objective: Objective) -> TrialRecord | None:
    """The feasible complete trial with the best value (the lowest number among equals)."""
    best: TrialRecord | None = None
    for r in sorted(recs, key=lambda r: r.number):
        if not r.feasible or r.value is None or not math.isfinite(r.value):
            continue
        if best is None or objective.better(r.value, best.value or 0.0):
            best = r
    return best


@dataclass
class _Running:
    trial: optuna.Trial
    params: dict[str, Value]
    handles: list[tuple[str, Any]]
    t0: float
    results: list[tuple[str, Any]] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    @property
    def waiting(self) -> int:
        return len(self.handles) - len(self.results) - len(self.errors)


def session_refs(
    settings: TuneSettings, executor: Executor, via: Literal["path", "store"]
) -> list[SessionRef]:
    """How the sessions reach the tasks: their paths, or their files through `share`."""
    if via == "path":
        return list(settings.sessions)
    return [executor.share(pack_session(Path(p))) for p in settings.sessions]


def run_trials(
    study: optuna.Study,
    settings: TuneSettings,
    executor: Executor,
    n_trials: int,
    sessions_via: Literal["path", "store"] = "path",
    on_trial: Callable[[TrialRecord], None] | None = None,
    parallel: int | None = None,
) -> list[TrialRecord]:
    """Run `n_trials` more trials of `study` on `executor`; returns the new trials' records
    in the order they finished.

    Args:
        study: the Optuna study (`open_study`).
        settings: what it searches.
        executor: where the tasks run.
        n_trials: trials to run now.
        sessions_via: how sessions reach the tasks (`session_refs`).
        on_trial: called with each finished trial (a progress bar).
        parallel: trials in flight at once (default: the executor's capacity).
    """
    from optuna.trial import TrialState

    if n_trials <= 0:
        return []
    study.sampler = make_sampler(settings, len(study.trials))
    dists = distributions(settings.space)
    refs = session_refs(settings, executor, sessions_via) if settings.sessions else []
    slots = max(1, parallel or executor.capacity)
    running: dict[int, _Running] = {}
    by_handle: dict[Any, tuple[int, str]] = {}
    asked = 0
    done: list[TrialRecord] = []

    def submit() -> None:
        nonlocal asked
        trial = study.ask(dists)
        t0 = time.monotonic()
        params = as_values(trial.params, settings.space)
        arb = settings.arbitration(params)
        handles: list[tuple[str, Any]] = []
        if settings.batch is not None:
            handles.append(("study", executor.submit(study_task, settings.batch, arb)))
        for ref in refs:
            for mode in paired(settings.mode):
                handles.append(("session", executor.submit(session_task, ref, mode.value, arb)))
        running[trial.number] = _Running(trial, params, handles, t0)
        for kind, h in handles:
            by_handle[h] = (trial.number, kind)
        asked += 1

    def finish(run: _Running) -> TrialRecord:
        trial = run.trial
        wall = time.monotonic() - run.t0
        metrics: dict[str, float] = {}
        seconds = 0.0
        error = run.errors[0] if run.errors else ""
        if not error:
            sessions = [r for kind, r in run.results if kind == "session"]
            for kind, r in run.results:
                if kind == "study":
                    metrics.update(r)
            if sessions:
                metrics.update(sessions_metrics(sessions, settings.mode))
            seconds = sum(v for k, v in metrics.items() if k.endswith(".seconds"))
        value: float | None = None
        cons: list[float] = []
        if not error:
            value = settings.objective.value(metrics)
            cons = settings.objective.constraints(metrics)
            if not math.isfinite(value):
                error = f"the objective is not a number ({value}): no actions to measure"
        trial.set_user_attr("wall_s", wall)
        trial.set_user_attr("seconds", seconds)
        if metrics:
            trial.set_user_attr("metrics", {k: finite(v) for k, v in metrics.items()})
        if error:
            trial.set_user_attr("error", error)
            study.tell(trial, state=TrialState.FAIL)
            value = None
        else:
            trial.set_user_attr("constraints", cons)
            for source, c in zip(settings.objective.sources, cons):
                trial.set_constraint(source, c)  # feasible when <= 0 (TPE reads it)
            study.tell(trial, value)
        return TrialRecord(
            number=trial.number,
            state="FAIL" if error else "COMPLETE",
            params=run.params,
            metrics=metrics,
            value=value,
            constraints=tuple(cons),
            seconds=seconds,
            wall_s=wall,
            error=error,
        )

    while len(done) < n_trials:
        while len(running) < slots and asked < n_trials:
            submit()
        handles = list(by_handle)
        for h in executor.ready(handles, timeout_s=0.5):
            number, kind = by_handle.pop(h)
            run = running[number]
            try:
                run.results.append((kind, executor.result(h)))
            except TaskError as exc:
                run.errors.append(str(exc))
            if run.waiting == 0:
                del running[number]
                rec = finish(run)
                done.append(rec)
                if on_trial is not None:
                    on_trial(rec)
    return done
