"""A map of where assistance helps: every mode of the study over a grid of the operator's
world (`dsteleop sim --sweep`, docs/sim.md).

A cell is one world, `Impairments` with goal noise `goal_sigma_m`, teleoperation delay
`delay_s` and single-view depth error `depth_sigma_m` set (the rest as configured). In each
cell every mode of the study (`SimConfig.modes`) runs on the same trajectories 0 .. N-1 of the
same seed, so the modes of a cell are paired, exactly as in one `dsteleop sim` run (a cell is
`batch.run_chunk` over its trajectories, in chunks of `CHUNK` for memory). Per cell, with the
paper's statistics (`dsteleop.arbitration.metrics`):

    per mode       success (Laplace estimate, adjusted-Wald 95 % CI), time (geometric mean,
                   95 % CI of the log mean), the share of censored times
    best mode      the highest success count; ties: the shorter geometric-mean time
    best scalar    the best (same rule) of the single-alpha modes present (`SCALAR_MODES`:
                   S and the tuned scalar baseline `scalar`)
    DS - scalar    the mean paired difference of success (DS minus the best scalar, per
                   trajectory) with its 95 % t interval; McNemar's exact and mid-p tests on
                   the paired outcomes; the N-1 chi-squared test; the ratio of geometric-mean
                   times with the paired t interval of the log difference
    verdict        `DS wins` / `DS loses` where McNemar's exact p < 0.05 (the sign of the
                   difference), otherwise `tie`

Cells run as Ray tasks (`app.tasks.cluster.RayExecutor`: a local cluster on 127.0.0.1, or an
existing one at `--address`); each finished cell is written at once to DIR/cells/<cell>.json
(with the settings that define it), so a stopped sweep resumes where it was (`--resume`
skips the cells whose file is there with the same settings). Nothing of the computation
depends on which worker ran a cell or in what order.

Designs (`DESIGNS`): `grid` runs every cell of the grid; `axes` only the cells that vary one
impairment at a time from the centre, the world's own values (`centre`): the centre and each
other level of each axis (7 cells of the default 3 x 3 x 3), for a study per level. By
default every cell runs with the study's one arbitration; with `CellConfig`s
(`--cell-configs DIR`) each cell runs with the configuration tuned for it, and its file and
the file's SHA-256 are recorded with its results (scripts/tune_sweep.py makes them).
sweep.md and sweep.png are drawn from the summary by app/study/sweep_report.py.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.jsonable import read_json
from dsteleop.app.operator.world import Impairments
from dsteleop.app.study import sweep_report
from dsteleop.app.study.batch import run_chunk
from dsteleop.app.study.objects import MAX_OBJECTS
from dsteleop.app.study.planar import SimConfig
from dsteleop.app.study.results import merge
from dsteleop.app.study.summary import censored, versus
from dsteleop.app.tasks.executor import Cluster, TaskError
from dsteleop.arbitration import ArbitrationConfig, Mode, metrics
from dsteleop.errors import ConfigError, InputError

SCHEMA = "dsteleop.sim_sweep/1"
#: Trajectories per batch inside a cell (a batch of 500 x 5 modes of 60 s trials needs ~1 GB).
CHUNK = 250
#: The grid's axes: name on the command line -> field of `Impairments` [unit].
AXES: dict[str, str] = {"goal": "goal_sigma_m", "delay": "delay_s", "depth": "depth_sigma_m"}
#: The objects world's two more axes (`axes_of`): the robot's perception error along its view
#: [m] (the lateral one keeps its ratio to it) and the number of objects, as the fields of
#: `Objects` they set.
OBJECT_AXES: dict[str, str] = {
    "perception": "objects.perception_depth_m",
    "objects": "objects.count",
}
#: Levels above 0 of an axis whose default is 0 (no literature value set yet): goal noise
#: [m], delay [s], depth error [m]. An axis with a default d > 0 has the levels 0, d, 2 d.
FALLBACK_LEVELS: dict[str, tuple[float, float]] = {
    "goal": (0.02, 0.04),
    "delay": (0.15, 0.30),
    "depth": (0.01, 0.02),
}
#: The single-alpha modes (one authority for every dimension): "best scalar" is the best of
#: those present.
SCALAR_MODES: tuple[str, ...] = ("S", "scalar")
ALPHA = 0.05
#: Which cells of the grid run (module docstring).
DESIGNS: tuple[str, ...] = ("grid", "axes")


def axes_of(cfg: SimConfig | None = None) -> dict[str, str]:
    """The axes of a study's world: `AXES`, and in the objects world `OBJECT_AXES` too."""
    if cfg is None or cfg.objects is None:
        return dict(AXES)
    return {**AXES, **OBJECT_AXES}


@dataclass(frozen=True)
class Grid:
    """The levels of each axis (`axes_of` the world, in that order); the cells are their
    product, the first axis slowest."""

    levels: dict[str, tuple[float, ...]]

    def cells(self) -> list[tuple[float, ...]]:
        """Every (goal, delay, depth[, perception, objects]) of the grid."""
        out: list[tuple[float, ...]] = [()]
        for axis in self.levels:
            out = [(*c, v) for c in out for v in self.levels[axis]]
        return out

    def to_dict(self) -> dict[str, list[float]]:
        return {axis: list(v) for axis, v in self.levels.items()}


def default_levels(axis: str, cfg: SimConfig | None = None) -> tuple[float, ...]:
    """0, the default d of `Impairments` and 2 d; 0 and `FALLBACK_LEVELS` when d is 0. In
    the objects world (`cfg.objects`) the impairments keep the study's one value (their map
    is the told-goal world's), the perception error has 0, d and 2 d of the world's, and the
    number of objects K - 1, K and K + 2."""
    if cfg is not None and cfg.objects is not None:
        o = cfg.objects
        if axis == "perception":
            d = o.perception_depth_m
            return (0.0, d, 2.0 * d) if d > 0 else (0.0, 0.02, 0.04)
        if axis == "objects":
            return tuple(float(k) for k in (o.count - 1, o.count, o.count + 2) if k >= 1)
        return (float(getattr(cfg.world, AXES[axis])),)
    d = float(getattr(Impairments(), AXES[axis]))
    return (0.0, d, 2.0 * d) if d > 0 else (0.0, *FALLBACK_LEVELS[axis])


def default_grid(cfg: SimConfig | None = None) -> Grid:
    return Grid({axis: default_levels(axis, cfg) for axis in axes_of(cfg)})


def parse_grid(specs: Sequence[str], cfg: SimConfig | None = None) -> Grid:
    """A grid from `AXIS=V1,V2,...` specs over the axes of `cfg`'s world (`axes_of`); an axis
    not given keeps its default levels.

    Raises:
        ConfigError: an unknown or repeated axis, a value that is not a finite number >= 0,
            no value, or a repeated value; a number of objects that is not a whole number
            in [1, 9] (one line).
    """
    axes = axes_of(cfg)
    levels = {axis: default_levels(axis, cfg) for axis in axes}
    seen: set[str] = set()
    for spec in specs:
        axis, sep, values = spec.partition("=")
        axis = axis.strip()
        if not sep or axis not in axes:
            raise ConfigError(
                f"--sweep {spec!r}: expected AXIS=V1,V2,... with AXIS one of {', '.join(axes)}"
            )
        if axis in seen:
            raise ConfigError(f"--sweep: axis {axis!r} given twice")
        seen.add(axis)
        out: list[float] = []
        for text in values.split(","):
            try:
                v = float(text)
            except ValueError:
                raise ConfigError(f"--sweep {spec!r}: {text.strip()!r} is not a number") from None
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"--sweep {spec!r}: levels must be finite and >= 0, got {v}")
            if v in out:
                raise ConfigError(f"--sweep {spec!r}: level {v:g} given twice")
            if axis == "objects" and not (v == int(v) and 1 <= v <= MAX_OBJECTS):
                raise ConfigError(
                    f"--sweep {spec!r}: a number of objects must be a whole number in "
                    f"[1, {MAX_OBJECTS}], got {v:g}"
                )
            out.append(v)
        levels[axis] = tuple(out)
    return Grid(levels)


def cell_name(cell: Sequence[float]) -> str:
    """The cell's file name stem, e.g. `goal0.02_delay0.15_depth0` (the objects world's
    `..._perception0.02_objects3`)."""
    names = list(AXES) if len(cell) == len(AXES) else [*AXES, *OBJECT_AXES]
    return "_".join(f"{axis}{v:g}" for axis, v in zip(names, cell, strict=True))


def _field(cfg: SimConfig, path: str) -> float:
    """The value of an axis's field (`AXES`: of `cfg.world`; `OBJECT_AXES`: `objects.<f>`)."""
    if path.startswith("objects."):
        assert cfg.objects is not None
        return float(getattr(cfg.objects, path.removeprefix("objects.")))
    return float(getattr(cfg.world, path))


def centre(cfg: SimConfig) -> tuple[float, ...]:
    """The world's own (goal, delay, depth[, perception, objects]) (`cfg.world`, `cfg.objects`):
    the cell the `axes` design varies one impairment at a time from."""
    return tuple(_field(cfg, f) for f in axes_of(cfg).values())


def design_cells(grid: Grid, design: str, middle: Sequence[float]) -> list[tuple[float, ...]]:
    """The cells of `grid` that `design` runs (module docstring), in the grid's order.

    Args:
        grid: the levels.
        design: one of `DESIGNS`.
        middle: the centre (`centre`) for `axes`.

    Raises:
        ConfigError: an unknown design, or (`axes`) a centre value that is not a level of its
            axis (one line).
    """
    if design not in DESIGNS:
        raise ConfigError(f"--sweep-design {design!r}: choose from {', '.join(DESIGNS)}")
    cells = grid.cells()
    if design == "grid":
        return cells
    for axis, v in zip(grid.levels, middle, strict=True):
        if v not in grid.levels[axis]:
            levels = ", ".join(f"{x:g}" for x in grid.levels[axis])
            raise ConfigError(
                f"--sweep-design axes: the world's {axis} {v:g} (the centre) is not one of "
                f"the axis's levels ({levels})"
            )
    return [c for c in cells if sum(a != b for a, b in zip(c, middle, strict=True)) <= 1]


@dataclass(frozen=True)
class CellConfig:
    """The configuration one cell runs with (`--cell-configs DIR`).

    Attributes:
        path: the file it was read from (DIR/<cell>.json).
        sha256: the hex SHA-256 of the file's bytes.
        arbitration: the arbitration it gives (with any `--param` on top).
        mode_arbitration: the modes with their own arbitration in it (its `modes` section;
            `SimConfig.mode_arbitration`).
    """

    path: Path
    sha256: str
    arbitration: ArbitrationConfig
    mode_arbitration: tuple[tuple[Mode, ArbitrationConfig], ...] = ()

    def record(self) -> dict[str, str]:
        """What a cell's file and the summary record of it."""
        return {"file": str(self.path), "sha256": self.sha256}


def cell_study(cfg: SimConfig, name: str, configs: dict[str, CellConfig] | None) -> SimConfig:
    """The study of the cell `name`: `cfg`, with its own arbitration where `configs` has it."""
    if configs is None:
        return cfg
    c = configs[name]
    return dataclasses.replace(cfg, arbitration=c.arbitration, mode_arbitration=c.mode_arbitration)


def with_world(cfg: SimConfig, cell: Sequence[float]) -> SimConfig:
    """The study `cfg` in the world of `cell` (its other impairments kept; in the objects world
    the perception error along the view and, in proportion, across it, and the number of
    objects)."""
    world = cfg.world.replace(**{f: float(v) for f, v in zip(AXES.values(), cell, strict=False)})
    changes: dict[str, Any] = {"world": world}
    if len(cell) > len(AXES):
        o = cfg.objects
        assert o is not None
        depth, count = float(cell[len(AXES)]), int(cell[len(AXES) + 1])
        ratio = o.perception_lateral_m / o.perception_depth_m if o.perception_depth_m > 0 else 0.25
        changes["objects"] = dataclasses.replace(
            o, perception_depth_m=depth, perception_lateral_m=ratio * depth, count=count
        )
    if "goal_sigma_m" in {f.name for f in dataclasses.fields(SimConfig)}:
        # Until the study reads its goal noise from `world` (the impairments' mechanisms),
        # the goal axis sets the field it reads today.
        changes["goal_sigma_m"] = world.goal_sigma_m
    return dataclasses.replace(cfg, **changes)


def settings(cfg: SimConfig) -> dict[str, Any]:
    """What defines a cell's results besides its world (stored in each cell's file, compared
    on `--resume`)."""
    d = cfg.to_dict()
    for k in ("world", "goal_sigma_m", "example", "max_paths"):
        d.pop(k, None)
    return json.loads(json.dumps(d))


# --- one cell (a Ray task) --------------------------------------------------------------------


def cell_task(cfg: SimConfig, cell: Sequence[float]) -> dict[str, Any]:
    """Run every mode of `cfg` in the world of `cell` on trajectories 0 .. N-1; per mode the
    per-trajectory success, time [s] and censoring, and the cell's compute time.

    Plain Python: it runs as a Ray task or in this process alike.
    """
    t0 = time.perf_counter()
    c = dataclasses.replace(with_world(cfg, cell), max_paths=0)
    n = c.trajectories
    chunks = [run_chunk(c, range(a, min(a + CHUNK, n))) for a in range(0, n, CHUNK)]
    res = merge(c, chunks)
    modes: dict[str, Any] = {}
    for name, r in res.modes.items():
        gave_up, limit = censored(c, r)
        modes[name] = {
            "success": r.success.astype(int).tolist(),
            "time_s": r.time_s.tolist(),
            "censored": (gave_up | limit).astype(int).tolist(),
        }
    return {
        "schema": SCHEMA,
        "cell": dict(zip(axes_of(cfg).values(), map(float, cell), strict=True)),
        "world": c.world.to_dict(),
        "settings": settings(cfg),
        "modes": modes,
        "seconds": time.perf_counter() - t0,
    }


def summarise_cell(data: dict[str, Any]) -> dict[str, Any]:
    """The statistics of one cell (module docstring) from its `cell_task` result."""
    per: dict[str, Any] = {}
    success = {m: np.asarray(v["success"], dtype=bool) for m, v in data["modes"].items()}
    times = {m: np.asarray(v["time_s"], dtype=np.float64) for m, v in data["modes"].items()}
    for m, v in data["modes"].items():
        s = success[m]
        sr = metrics.success_rate(int(s.sum()), int(s.size))
        gm = metrics.geometric_mean(times[m])
        per[m] = {
            "success": sr.laplace,
            "successes": sr.successes,
            "n": sr.n,
            "success_ci95": [sr.ci_low, sr.ci_high],
            "time_s": gm.mean,
            "time_ci95": [gm.ci_low, gm.ci_high],
            "censored_share": float(np.mean(v["censored"])),
        }

    def best(names: Iterable[str]) -> str | None:
        names = list(names)
        if not names:
            return None
        return min(names, key=lambda m: (-per[m]["successes"], per[m]["time_s"]))

    out: dict[str, Any] = {
        "cell": data["cell"],
        "name": cell_name(list(data["cell"].values())),
        "modes": per,
        "best_mode": best(per),
        "seconds": data.get("seconds"),
    }
    if "configuration" in data:
        out["configuration"] = data["configuration"]
    scalar = best(m for m in SCALAR_MODES if m in per)
    out["best_scalar"] = scalar
    if "DS" in per and scalar is not None:
        ds, sc = success["DS"], success[scalar]
        diff = metrics.paired_difference(ds.astype(float), sc.astype(float))
        mc = metrics.mcnemar(ds, sc)
        chi = metrics.n1_chi_squared(int(ds.sum()), ds.size, int(sc.sum()), sc.size)
        logd = metrics.paired_difference(np.log(times["DS"]), np.log(times[scalar]))
        if mc.p_exact < ALPHA and diff.mean != 0:
            verdict = "DS wins" if diff.mean > 0 else "DS loses"
        else:
            verdict = "tie"
        out["ds_minus_best_scalar"] = {
            "versus": scalar,
            "success_difference": diff.mean,
            "ci95": [diff.ci_low, diff.ci_high],
            "mcnemar": dataclasses.asdict(mc),
            "n1_chi2": dataclasses.asdict(chi),
            "time_ratio": math.exp(logd.mean),
            "time_ratio_ci95": [math.exp(logd.ci_low), math.exp(logd.ci_high)],
            "verdict": verdict,
        }
    if "DSC" in per:  # the objects world: DSC against every other mode (app.study.summary)
        out["dsc_versus"] = {
            m: {**versus(success["DSC"], success[m], times["DSC"], times[m])}
            for m in per
            if m != "DSC"
        }
        for v in out["dsc_versus"].values():
            v["verdict"] = v["verdict"].replace("a ", "DSC ")
    return out


# --- the sweep --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepRun:
    """What a sweep did: its summary (sweep.json) and the cells that failed."""

    summary: dict[str, Any]
    failed: dict[str, str]


def cells_dir(out: Path) -> Path:
    return out / "cells"


def load_done(
    out: Path,
    cfg: SimConfig,
    cells: Sequence[tuple[float, ...]],
    configs: dict[str, CellConfig] | None = None,
) -> dict[str, dict[str, Any]]:
    """The cells of `cells` already in DIR/cells with the same settings (each cell's own
    arbitration, `cell_study`) and, with `configs`, from the same configuration file.

    Raises:
        InputError: a cell file is unreadable, or holds other settings or another
            configuration (one line).
    """
    done = {}
    for cell in cells:
        name = cell_name(cell)
        path = cells_dir(out) / f"{name}.json"
        if not path.exists():
            continue
        data = read_json(path, "--resume: a finished cell")
        if not isinstance(data, dict):
            raise InputError(f"--resume: {path} is not a finished cell (not a JSON object)")
        if data.get("settings") != settings(cell_study(cfg, name, configs)):
            raise InputError(
                f"--resume: {path} was computed with other settings (trajectories, seed, modes, "
                "operator or arbitration); use a new --out"
            )
        record = None if configs is None else configs[name].record()
        if data.get("configuration") != record:
            had = data.get("configuration") or {"file": "one configuration for every cell"}
            raise InputError(
                f"--resume: {path} was computed with another configuration ({had.get('file')}); "
                "use a new --out"
            )
        done[name] = data
    return done


def check_out(out: Path, resume: bool) -> None:
    """Without `--resume` DIR must not hold a sweep; with it, it must.

    Raises:
        InputError: one line saying which.
    """
    held = (out / "sweep.json").exists() or any(cells_dir(out).glob("*.json"))
    if held and not resume:
        raise InputError(f"{out} holds a sweep already: --resume to continue it, or a new --out")
    if resume and not held:
        raise InputError(f"--resume: {out} holds no sweep")


def run_sweep(
    cfg: SimConfig,
    grid: Grid,
    out: Path,
    executor: Callable[[], Cluster],
    on_cell: Callable[[str, bool], None] | None = None,
    design: str = "grid",
    configs: dict[str, CellConfig] | None = None,
) -> SweepRun:
    """Run the cells of `design` over `grid` not yet in DIR/cells, write each as it
    finishes, and return the summary of every cell.

    Args:
        cfg: the study (its trajectories, seed, modes, operator and arbitration).
        grid: the levels.
        out: the output folder (DIR/cells is created).
        executor: makes the task executor (`RayExecutor`) when a cell needs computing; it
            is closed when the cells are done.
        on_cell: called with each cell's name and whether it was computed (False: resumed).
        design: which cells run (`design_cells`).
        configs: per cell name its configuration (every cell of the design has one); None:
            every cell runs with `cfg.arbitration`.
    """
    t0 = time.perf_counter()
    cells = design_cells(grid, design, centre(cfg))
    if configs is not None:
        missing = [cell_name(c) for c in cells if cell_name(c) not in configs]
        if missing:
            raise InputError(f"no configuration for cell {missing[0]} ({len(missing)} missing)")
    cells_dir(out).mkdir(parents=True, exist_ok=True)
    done = load_done(out, cfg, cells, configs)
    for name in done:
        if on_cell is not None:
            on_cell(name, False)
    todo = [c for c in cells if cell_name(c) not in done]
    failed: dict[str, str] = {}
    cluster: dict[str, Any] | None = None
    start_s = 0.0
    if todo:
        t1 = time.perf_counter()
        with executor() as ex:
            start_s = time.perf_counter() - t1
            cluster = ex.describe()
            if configs is None:
                shared = ex.share(cfg)
                pending = {ex.submit(cell_task, shared, c): c for c in todo}
            else:
                pending = {
                    ex.submit(cell_task, cell_study(cfg, cell_name(c), configs), c): c for c in todo
                }
            while pending:
                for h in ex.ready(list(pending), 1.0):
                    cell = pending.pop(h)
                    name = cell_name(cell)
                    try:
                        data = ex.result(h)
                    except TaskError as exc:
                        failed[name] = str(exc)
                        continue
                    if configs is not None:
                        data["configuration"] = configs[name].record()
                    _write_atomic(cells_dir(out) / f"{name}.json", data)
                    done[name] = data
                    if on_cell is not None:
                        on_cell(name, True)
    summaries = [summarise_cell(done[cell_name(c)]) for c in cells if cell_name(c) in done]
    summary = {
        "schema": SCHEMA,
        "grid": grid.to_dict(),
        "axes": axes_of(cfg),
        "trajectories": cfg.trajectories,
        "seed": cfg.seed,
        "modes": [m.value for m in cfg.modes],
        "operator": cfg.operator,
        "scalar_modes": [m for m in SCALAR_MODES if m in {x.value for x in cfg.modes}],
        "alpha": ALPHA,
        "cells": summaries,
        "counts": _counts(summaries),
        "computed": len(todo) - len(failed),
        "resumed": len(cells) - len(todo),
        "failed": failed,
        "cluster": cluster,
        "cluster_start_s": round(start_s, 3),
        "elapsed_s": round(time.perf_counter() - t0, 3),
        "config": settings(cfg),
        "world": cfg.world.to_dict(),
    }
    if any("dsc_versus" in c for c in summaries):
        summary["dsc_counts"] = _dsc_counts(summaries)
    if cfg.objects is not None:
        summary["objects"] = cfg.objects.to_dict()
    if design != "grid":
        summary["design"] = design
        summary["centre"] = dict(zip(axes_of(cfg).values(), centre(cfg), strict=True))
    if configs is not None:
        # Each cell has its own arbitration (its file and hash per cell, the parameters in
        # DIR/cells/<cell>.json): the study's one is none of them.
        config = settings(cfg)
        config.pop("arbitration", None)
        summary["config"] = config
        summary["cell_configs"] = {cell_name(c): configs[cell_name(c)].record() for c in cells}
    return SweepRun(summary, failed)


def _counts(cells: Sequence[dict[str, Any]]) -> dict[str, int]:
    out = {"DS wins": 0, "tie": 0, "DS loses": 0}
    for c in cells:
        d = c.get("ds_minus_best_scalar")
        if d is not None:
            out[d["verdict"]] += 1
    return out


def _dsc_counts(cells: Sequence[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per mode DSC was set against: the cells where DSC wins, ties and loses."""
    out: dict[str, dict[str, int]] = {}
    for c in cells:
        for m, v in c.get("dsc_versus", {}).items():
            out.setdefault(m, {"DSC wins": 0, "tie": 0, "DSC loses": 0})[v["verdict"]] += 1
    return out


def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, allow_nan=False) + "\n")
    os.replace(tmp, path)


# --- the command (`dsteleop sim --sweep`) -------------------------------------------------------


def run_command(
    cfg: SimConfig,
    grid: Grid,
    out: Path,
    address: str | None,
    workers: int | None,
    resume: bool,
    figures: bool,
    show_progress: bool,
    design: str = "grid",
    configs: dict[str, CellConfig] | None = None,
) -> int:
    """Run the sweep (the cells of `design`, each with its configuration of `configs` where
    given, as `run_sweep`), write DIR/sweep.json, sweep.md and sweep.png, print one JSON line.

    Returns:
        0, or 2 when a cell failed (the outputs hold the others; the first error is raised
        as one line).

    Raises:
        InputError: DIR holds a sweep without `--resume` (or none with it), a stored cell has
            other settings or another configuration, the cluster cannot start or be reached,
            a cell failed.
        ConfigError: the design does not fit the grid (`design_cells`).
    """
    import sys

    from dsteleop.app.tasks.cluster import RayExecutor, check_reachable
    from dsteleop.app.tasks.progress import Progress

    check_out(out, resume)
    check_reachable(address)
    cells = design_cells(grid, design, centre(cfg))
    with Progress(len(cells), sys.stderr, show_progress, "sweep", "cells") as bar:
        run = run_sweep(
            cfg,
            grid,
            out,
            lambda: RayExecutor(address, workers),
            lambda _name, _computed: bar.advance(),
            design,
            configs,
        )
    s = run.summary
    (out / "sweep.json").write_text(json.dumps(s, indent=2, allow_nan=False) + "\n")
    (out / "sweep.md").write_text(sweep_report.markdown(s))
    files = ["sweep.json", "sweep.md"]
    if figures and s["cells"]:
        sweep_report.figure(s, out / "sweep.png")
        files.append("sweep.png")
    json.dump(
        {
            "out": str(out),
            "files": files,
            "cells": len(cells),
            "computed": s["computed"],
            "resumed": s["resumed"],
            "failed": len(run.failed),
            "counts": s["counts"],
            "trajectories": s["trajectories"],
            "modes": s["modes"],
            "cluster": s["cluster"],
            "elapsed_s": s["elapsed_s"],
        },
        sys.stdout,
    )
    sys.stdout.write("\n")
    if run.failed:
        name, error = next(iter(run.failed.items()))
        raise InputError(
            f"{len(run.failed)} cell(s) failed, first {name}: {error} (--resume reruns them)"
        )
    return 0
