"""`dsteleop sim`: the paper's simulation study (Section IV-A/B), S vs DS on planar trajectories.

    dsteleop sim --trajectories 1000 --seed 0 --out DIR [--workers N]
                 [--operator closed-loop|side|aligned|deviate]
                 [--param NAME=VALUE] [--config FILE.json]

writes DIR/summary.json, DIR/summary.md (shaped like the paper's Table I) and PNG figures
shaped like Fig. 5b-5d and 6 (`--example K` picks the trajectory of 5c, 5d and 6), and prints
one JSON object on stdout. With `--sweep [AXIS=V1,V2,...]...` it runs every mode over a grid
of the operator's world instead (`app/study/sweep.py`: Ray tasks on a local cluster or
`--address`, `--resume`; `--sweep-design axes` for one impairment at a time, `--cell-configs
DIR` for a configuration per cell), writing DIR/sweep.json, sweep.md and sweep.png. The computation
is app/study/ (pure: the world `planar.py`, the batched simulation `batch.py`, the results
`results.py`, the summary `summary.py`); this module is the edge: arguments, progress bar, files.
docs/sim.md describes the study and the operator.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from dsteleop.app.cli.options import add_config_options, configuration, parse_params
from dsteleop.app.cli.world_options import add_world_arguments, world_overrides
from dsteleop.app.outpaths import created_dir, output_dir
from dsteleop.app.tasks.progress import Progress
from dsteleop.arbitration import ArbitrationConfig, Mode, registered
from dsteleop.errors import ConfigError, InputError

if TYPE_CHECKING:  # heavy: imported when a command runs
    from dsteleop.app.study.planar import SimConfig
    from dsteleop.app.study.sweep import CellConfig, Grid

log = logging.getLogger("dsteleop.sim")

OPERATORS = ("closed-loop", "side", "aligned", "deviate")


@dataclass(frozen=True)
class SimCommand:
    """The `sim` command's settings.

    Attributes:
        study: the study's configuration (`app.study.planar.SimConfig`).
        out: the output folder.
        workers: processes.
        figures: draw the PNG figures.
        progress: draw the progress bar (None: on a terminal).
    """

    study: SimConfig
    out: Path
    workers: int
    figures: bool
    progress: bool | None
    sweep: Grid | None = None
    address: str | None = None
    resume: bool = False
    design: str = "grid"
    cell_configs: dict[str, CellConfig] | None = None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trajectories",
        type=int,
        default=None,
        metavar="N",
        help="number of operator trajectories (default 1000; with --sweep 500 per cell)",
    )
    parser.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    parser.add_argument(
        "--out",
        required=True,
        type=output_dir,
        metavar="DIR",
        help="output directory (created if missing)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=0,
        metavar="N",
        help="processes (default 0: one per core, at most 4)",
    )
    parser.add_argument(
        "--operator",
        default="closed-loop",
        help=(
            "closed-loop (default: watches the robot and steers it to the true handle), or "
            "open loop: side (the paper's scenario: agrees on position, prefers another "
            "heading), aligned (agrees on every dimension), deviate (Fig. 6: the heading "
            "deviates late)"
        ),
    )
    parser.add_argument(
        "--modes",
        default=None,
        help="comma-separated arbitration modes (default: every registered one, "
        f"{','.join(m.value for m in registered())})",
    )
    parser.add_argument(
        "--example",
        type=int,
        default=None,
        metavar="K",
        help="trajectory drawn in Fig. 5c, 5d and 6 (default: the first that moves y before x)",
    )
    add_world_arguments(parser)
    add_config_options(parser)
    parser.add_argument(
        "--sweep",
        nargs="*",
        default=None,
        metavar="AXIS=V1,V2,...",
        help=(
            "run every mode over a grid of the operator's world: AXIS is goal (goal noise sigma "
            "[m]), delay [s] or depth (depth error sigma [m]); an axis not given keeps its "
            "default levels (docs/sim.md). Cells run as Ray tasks; writes sweep.json/md/png"
        ),
    )
    parser.add_argument(
        "--sweep-design",
        choices=("grid", "axes"),
        default=None,
        help="with --sweep: grid (default: every cell) or axes (the world's centre and each "
        "other level of one axis at a time: 7 cells of the default grid)",
    )
    parser.add_argument(
        "--cell-configs",
        type=Path,
        default=None,
        metavar="DIR",
        help="with --sweep: each cell runs with the configuration DIR/<cell>.json (a --config "
        "file, e.g. made by scripts/tune_sweep.py); a cell without one is refused",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="with --sweep: an existing Ray cluster (auto, HOST:PORT or ray://HOST:PORT); "
        "default: a local cluster of --workers CPUs on 127.0.0.1",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="with --sweep: continue the sweep in --out, skipping the cells already there",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    bar = parser.add_mutually_exclusive_group()
    bar.add_argument(
        "--progress",
        dest="progress",
        action="store_true",
        default=None,
        help="always draw the progress bar",
    )
    bar.add_argument(
        "--no-progress", dest="progress", action="store_false", help="never draw the progress bar"
    )


def command(args: argparse.Namespace) -> SimCommand:
    """The command's settings; bad values raise ConfigError with one line."""
    from dsteleop.app.study.planar import SimConfig, all_modes
    from dsteleop.app.study.run import workers_for

    modes = (
        all_modes(inference=args.world == "objects")
        if args.modes is None
        else tuple(Mode.parse(s.strip()) for s in str(args.modes).split(","))
    )
    if args.cell_configs is not None and args.config is not None:
        raise ConfigError("--config and --cell-configs are mutually exclusive")
    arb, own = study_configuration(args.config, args.param)
    if args.operator not in OPERATORS:
        raise ConfigError(
            f"unknown operator {args.operator!r} (choose from {', '.join(OPERATORS)})"
        )
    extra = world_overrides(args)
    sweep = None
    if args.sweep is not None:
        from dsteleop.app.study.sweep import parse_grid

        sweep = parse_grid(args.sweep, SimConfig(**extra))
        if args.address is not None:
            from dsteleop.app.tasks.cluster import parse_address

            parse_address(args.address)
    elif (
        args.address is not None
        or args.resume
        or args.sweep_design is not None
        or args.cell_configs is not None
    ):
        raise ConfigError("--address, --resume, --sweep-design and --cell-configs go with --sweep")
    trajectories = args.trajectories
    if trajectories is None:
        trajectories = 500 if sweep is not None else 1000
    if trajectories < 1:
        raise ConfigError(f"--trajectories must be >= 1, got {trajectories}")
    if sweep is not None and trajectories < 2:
        raise ConfigError(
            f"--sweep needs --trajectories >= 2 (paired intervals), got {trajectories}"
        )
    if sweep is not None and args.workers < 0:
        raise ConfigError(f"--workers must be >= 0 (0: every core), got {args.workers}")
    study = SimConfig(
        trajectories=trajectories,
        seed=args.seed,
        operator=args.operator,
        modes=modes,
        example=args.example,
        arbitration=arb,
        mode_arbitration=tuple((m, a) for m, a in own if m in modes),
        **extra,
    )
    design = args.sweep_design or "grid"
    cell_configs = None
    if sweep is not None:
        from dsteleop.app.study.sweep import centre, design_cells

        cells = design_cells(sweep, design, centre(study))
        if args.cell_configs is not None:
            cell_configs = read_cell_configs(args.cell_configs, cells, args.param)
    return SimCommand(
        study=study,
        out=Path(args.out),
        workers=args.workers if sweep is not None else workers_for(args.workers, trajectories),
        figures=not args.no_figures,
        progress=args.progress,
        sweep=sweep,
        address=args.address,
        resume=bool(args.resume),
        design=design,
        cell_configs=cell_configs,
    )


def read_cell_configs(
    folder: Path, cells: list[tuple[float, ...]], params: list[str]
) -> dict[str, CellConfig]:
    """Per cell name its `CellConfig` from `folder`/<cell>.json (read as a `--config` file,
    with `--param` on top): every cell must have one, so none falls back to the defaults.

    Raises:
        InputError: no such folder, a cell without a file, an unreadable file (one line).
        ConfigError: a file that is not a configuration (one line).
    """
    import hashlib

    from dsteleop.app.study.sweep import CellConfig, cell_name

    if not folder.is_dir():
        raise InputError(f"--cell-configs: not a folder: {folder}")
    names = [cell_name(c) for c in cells]
    missing = [n for n in names if not (folder / f"{n}.json").is_file()]
    if missing:
        raise InputError(
            f"--cell-configs {folder}: no {missing[0]}.json ({len(missing)} of {len(names)} "
            "cells have no configuration; tune them with scripts/tune_sweep.py)"
        )
    out: dict[str, CellConfig] = {}
    for name in names:
        path = folder / f"{name}.json"
        arb, own = study_configuration(path, params, "--cell-configs")
        try:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError as exc:
            raise InputError(f"--cell-configs {path}: {exc}") from None
        out[name] = CellConfig(path, digest, arb, own)
    return out


def study_configuration(
    path: Path | None, params: list[str], option: str = "--config"
) -> tuple[ArbitrationConfig, tuple[tuple[Mode, ArbitrationConfig], ...]]:
    """The study's configuration of a `--config` file (options.py's reader, `--param` on
    top) and its modes that run with their own (`SimConfig.mode_arbitration`): the file's
    `modes` section, `{"MODE": {arbitration fields}, ...}` (scripts/tune_sweep.py writes it
    for modes tuned apart that share fields), each over the file's arbitration, `--param` on
    top of each."""
    file = configuration(path, params, option, sections=("modes",))
    if path is None:
        return file.arbitration, ()
    section = file.sections.get("modes", {})
    if not isinstance(section, dict) or not all(isinstance(v, dict) for v in section.values()):
        raise ConfigError(f"{option} {path}: `modes` must map each mode to its fields")
    base = file.file_fields
    given = parse_params(params)
    own: list[tuple[Mode, ArbitrationConfig]] = []
    for name, fields in section.items():
        try:
            mode = Mode.parse(name)
            own.append((mode, ArbitrationConfig.from_dict({**base, **fields, **given})))
        except (ConfigError, TypeError) as exc:
            raise ConfigError(f"{option} {path}: modes.{name}: {exc}") from None
    return file.arbitration, tuple(own)


def run(args: argparse.Namespace) -> int:
    t0 = time.monotonic()
    cmd = command(args)
    # A study that fails leaves no empty --out behind (outpaths.created_dir).
    with created_dir(cmd.out) as out:
        return _run(cmd, out, t0)


def _run(cmd: SimCommand, out: Path, t0: float) -> int:
    from dsteleop.app.study import figures, planar, report
    from dsteleop.app.study.results import StudyResult
    from dsteleop.app.study.run import simulate_all
    from dsteleop.app.study.summary import summarise

    cfg = cmd.study
    if cmd.sweep is not None:
        from dsteleop.app.study.sweep import run_command

        show = sys.stderr.isatty() if cmd.progress is None else bool(cmd.progress)
        return run_command(
            cfg,
            cmd.sweep,
            out,
            cmd.address,
            cmd.workers or None,
            cmd.resume,
            cmd.figures,
            show,
            cmd.design,
            cmd.cell_configs,
        )
    modes = ",".join(m.value for m in cfg.modes)
    log.info(
        "sim: %d trajectories, operator %s, modes %s, %d worker(s), out %s",
        *(cfg.trajectories, cfg.operator, modes, cmd.workers, out),
    )
    # Fig. 5/6 and the x-per-y remark come from an operator who does not watch the robot, as
    # in the paper: the run itself for an open-loop operator, else an open-loop companion.
    fig_cfg = planar.figure_study(cfg)
    # The companion first: its figure is drawn here while the workers run the study.
    studies = [cfg] if fig_cfg is cfg else [fig_cfg, cfg]
    show = sys.stderr.isatty() if cmd.progress is None else bool(cmd.progress)
    files = ["summary.json", "summary.md"]
    example: int | None = None

    def example_figures() -> None:
        # Needs only the configuration: chosen and drawn while the workers simulate.
        nonlocal example
        example = (
            fig_cfg.example if fig_cfg.example is not None else planar.first_lead_index(fig_cfg)
        )
        files.extend(figures.write_example_figures(fig_cfg, example, out))

    def distribution_figure(i: int, res: StudyResult) -> None:
        if i == 0:  # the figure study's (the only study, or its companion's)
            files.insert(2, figures.write_distribution_figure(res, out))

    total = sum(c.trajectories * len(c.modes) * c.runs for c in studies)
    with Progress(total, sys.stderr, show, "sim", "trajectory-modes") as bar:
        results = simulate_all(
            studies, cmd.workers, bar, example_figures if cmd.figures else None,
            distribution_figure if cmd.figures else None,
        )  # fmt: skip
    fig_result, result = results[0], results[-1]
    summary = summarise(result, fig_result)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    (out / "summary.md").write_text(report.markdown(summary))
    printed = report.brief(summary, out, files, time.monotonic() - t0, cmd.workers)
    printed["example"] = example
    json.dump(printed, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0
