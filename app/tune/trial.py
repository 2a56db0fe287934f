"""The trial functions of `dsteleop tune`: plain Python, no Ray, no Optuna.

A trial evaluates one arbitration configuration, S and the tuned mode paired, on its sources
(app/tune/objective.py). Each function here is one unit of work (one task on a cluster) and
takes only picklable values, so the same function runs in this process, in a process pool or
as a Ray task:

    study_task     the tuning batch of the closed-loop study (`app.study.batch.run_chunk`,
                   S and the tuned mode of every trajectory in one batch) -> flat metrics
    study_chunk    some trajectories of a batch -> the per-trajectory results (`ChunkResult`;
                   the held-out evaluation merges them)
    session_task   one headless replay of one session in one mode (`app.replay.core`)
                   -> that run's summary

A session reaches a worker as its path (a folder every worker can read) or as its files'
bytes (`pack_session`; on a cluster, through the object store), unpacked there into a
temporary folder.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app.study import metric_table
from dsteleop.app.study.batch import run_chunk
from dsteleop.app.study.grasps import Grasps
from dsteleop.app.study.metric_table import Metric
from dsteleop.app.study.objects import Objects
from dsteleop.app.study.planar import SimConfig
from dsteleop.app.study.results import ChunkResult
from dsteleop.app.study.summary import headline
from dsteleop.app.tune.objective import key
from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import ConfigError, InputError

#: The files of a session a replay reads (no video: replays do not re-track).
SESSION_FILES: tuple[str, ...] = ("meta.json", "ticks.jsonl")


def paired(mode: str) -> tuple[Mode, Mode]:
    """The modes of a trial: S, the reference, and the tuned mode."""
    return (Mode.S, Mode.parse(mode))


#: A session as a worker gets it: a path, or (name, {file name: bytes}).
SessionRef = str | tuple[str, dict[str, bytes]]


@dataclass(frozen=True)
class StudyBatch:
    """Trajectories of the closed-loop study that a configuration is scored on.

    Attributes:
        trajectories: how many: indices 0 .. trajectories - 1.
        seed: the study's master seed; trajectory n is seeded by (seed, n) alone.
        mode: the tuned mode (paired with S).
        world: the study's world, `SimConfig` overrides (`world_of`; empty: the default).
    """

    trajectories: int
    seed: int
    mode: str = "DS"
    world: tuple[tuple[str, Any], ...] = ()

    def config(self, arbitration: ArbitrationConfig) -> SimConfig:
        """The study of this batch under `arbitration`, S and the mode, in its world, no
        paths kept."""
        return SimConfig(
            trajectories=self.trajectories,
            seed=self.seed,
            modes=paired(self.mode),
            max_paths=0,
            arbitration=arbitration,
            **sim_overrides(dict(self.world)),
        )


#: The study's world: `SimConfig` field overrides as JSON values (app/cli/world_options.py's
#: `world_overrides`, a dataclass field such as `world` as a dict of its changed fields).
World = tuple[tuple[str, Any], ...]

#: `SimConfig` settings that are None in the default world, by the class they hold.
OPTIONAL_DATACLASSES: dict[str, type] = {"grasps": Grasps, "objects": Objects}


def world_of(overrides: Mapping[str, Any]) -> World:
    """`SimConfig` field overrides (`world_overrides`) as a `StudyBatch.world`: sorted pairs of
    JSON values, a dataclass as the dict of the fields it changes from the study's default
    (so the stored settings name only what the options set)."""
    default = SimConfig()
    out: list[tuple[str, Any]] = []
    for name, value in sorted(overrides.items()):
        if not hasattr(default, name):
            raise ConfigError(f"the study has no setting {name!r}")
        v = value
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            base = getattr(default, name)
            v = {
                f.name: _plain(getattr(value, f.name))
                for f in dataclasses.fields(value)
                if base is None or getattr(value, f.name) != getattr(base, f.name)
            }
        out.append((name, _plain(v)))
    return tuple(out)


def sim_overrides(world: Mapping[str, Any]) -> dict[str, Any]:
    """`world_of`'s inverse: the `SimConfig` field overrides (a dict of a dataclass field
    replaces those fields of the study's default; lists become tuples again)."""
    default = SimConfig()
    out: dict[str, Any] = {}
    for name, v in world.items():
        base = getattr(default, name, None)
        if base is None and name in OPTIONAL_DATACLASSES and isinstance(v, dict):
            # A setting the default world does not have (the disagreement world's grasps).
            out[name] = OPTIONAL_DATACLASSES[name](**{k: _tuple(x) for k, x in v.items()})
        elif dataclasses.is_dataclass(base) and isinstance(v, dict):
            out[name] = dataclasses.replace(base, **{k: _tuple(x) for k, x in v.items()})  # type: ignore[type-var]
        else:
            out[name] = _tuple(v)
    return out


def describe_world(world: World) -> str:
    """The world in words: the study's default, or the settings that differ from it."""
    if not world:
        return "the study's default world (docs/operator.md)"
    parts = []
    for name, v in world:
        if isinstance(v, dict):
            parts += [f"{name}.{k} = {json.dumps(x)}" for k, x in v.items()]
        else:
            parts.append(f"{name} = {json.dumps(v)}")
    return "the study's world with " + ", ".join(parts)


def _plain(v: Any) -> Any:
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def _tuple(v: Any) -> Any:
    return tuple(_tuple(x) for x in v) if isinstance(v, list) else v


def study_chunk(
    batch: StudyBatch, arbitration: Mapping[str, Any], indices: Sequence[int]
) -> ChunkResult:
    """Trajectories `indices` of `batch` under the configuration `arbitration` (a dict of
    ArbitrationConfig fields; an invalid one raises ConfigError), S and the mode in one batch."""
    cfg = batch.config(ArbitrationConfig.from_dict(dict(arbitration)))
    return run_chunk(cfg, list(indices))


def study_task(batch: StudyBatch, arbitration: Mapping[str, Any]) -> dict[str, float]:
    """One trial on the study: every trajectory of `batch`, S and the tuned mode.

    Returns:
        `study.<MODE>.<metric>` for each of `app.study.summary.headline`'s keys, and
        `study.seconds`, the time this took [s].
    """
    t0 = time.perf_counter()
    chunk = study_chunk(batch, arbitration, range(batch.trajectories))
    out: dict[str, float] = {}
    for mode in paired(batch.mode):
        for name, v in headline(chunk.modes[mode.value]).items():
            out[key("study", mode.value, name)] = v
    out["study.seconds"] = time.perf_counter() - t0
    return out


def pack_session(folder: Path) -> tuple[str, dict[str, bytes]]:
    """A session's name and the bytes of its files (`SESSION_FILES`), to ship to workers
    that cannot read its folder."""
    files = {}
    for name in SESSION_FILES:
        p = Path(folder) / name
        if p.is_file():
            try:
                files[name] = p.read_bytes()
            except OSError as exc:
                raise InputError(f"{p}: unreadable ({exc.strerror})") from None
    return Path(folder).name, files


def session_task(session: SessionRef, mode: str, arbitration: Mapping[str, Any]) -> dict[str, Any]:
    """One replay: `session`'s recorded hand through a fresh loop and a fresh PyBullet robot
    in `mode` under the configuration `arbitration` (as `dsteleop replay --robot simulated
    --config`).

    Returns:
        the run's summary (`app.replay.core.session_summary`: name, duration_s, modes.<MODE>
        with success, time_s, cosine_distance, agreement, ...) and `seconds` [s].
    """
    t0 = time.perf_counter()
    config = ArbitrationConfig.from_dict(dict(arbitration))
    if isinstance(session, str):
        summary = _replay(Path(session), Mode.parse(mode), config)
    else:
        name, files = session
        with tempfile.TemporaryDirectory(prefix="dsteleop-session-") as tmp:
            folder = Path(tmp) / name
            folder.mkdir()
            for fname, data in files.items():
                (folder / fname).write_bytes(data)
            summary = _replay(folder, Mode.parse(mode), config)
    summary["seconds"] = time.perf_counter() - t0
    return summary


def _replay(folder: Path, mode: Mode, config: ArbitrationConfig) -> dict[str, Any]:
    from dsteleop.app.replay import core
    from dsteleop.app.session.reader import read_session

    session = read_session(folder)
    loop = {**session.meta.get("loop", {}), "arbitration": config.to_dict()}
    session = dataclasses.replace(session, meta={**session.meta, "loop": loop})
    trace = core.replay_session(session, mode, robot="simulated")
    return core.session_summary(session.name, trace.recorded_s, [trace])


def _session_values(metric: Metric, a: Mapping[str, Any]) -> dict[str, float]:
    """One metric's values over sessions from `dsteleop replay`'s aggregate of one mode `a`
    (`app.replay.core.aggregate`): a rate's Laplace estimate, its count and n; a log
    metric's geometric mean; a linear one's Table I statistic (the geometric mean over
    sessions); nan where there is none."""
    if metric.scale == "rate":
        sr = a[metric.summary_key]
        return {
            metric.name: sr["laplace"] if sr else math.nan,
            metric.count_key: float(sr["successes"]) if sr else 0.0,
            "n": float(a["n"]),
        }
    if metric.scale == "log":
        gm = a[metric.name]
        return {metric.name: _num(gm["mean"]) if gm else math.nan}
    return {metric.name: _num(a[metric.name])}


def sessions_metrics(runs: Sequence[Mapping[str, Any]], mode: str = "DS") -> dict[str, float]:
    """The sessions' metrics of one trial from its replays (`session_task` results, any
    order): per mode (S and the tuned `mode`), over sessions, as `dsteleop replay` aggregates
    them.

    Returns:
        `sessions.<MODE>.<metric>` per metric of the table (`_session_values`: success as a
        Laplace estimate with successes and n, time_s, cosine_distance and agreement as
        geometric means over sessions), and `sessions.seconds`, the replays' summed time [s].
    """
    from dsteleop.app.replay.core import aggregate

    by_name: dict[str, dict[str, Any]] = {}
    for run in runs:
        entry = by_name.setdefault(
            run["name"], {"name": run["name"], "duration_s": run["duration_s"], "modes": {}}
        )
        entry["modes"].update(run["modes"])
    sessions = [by_name[n] for n in sorted(by_name)]
    modes = paired(mode)
    agg, _ = aggregate(sessions, [m.value for m in modes])
    out: dict[str, float] = {}
    for m in modes:
        a = agg[m.value]
        for metric in metric_table.tuning_order():
            for name, v in _session_values(metric, a).items():
                out[key("sessions", m.value, name)] = v
    out["sessions.seconds"] = float(sum(r.get("seconds", 0.0) for r in runs))
    return out


def _num(x: float | None) -> float:
    return math.nan if x is None else float(x)
