"""`dsteleop tune`: hyper-parameter studies of the arbitration, trials as Ray tasks.

    dsteleop tune --objective study|sessions|both --trials N|--trials-per-param K --out DIR
                  [--mode M] [--space NAME=SPEC ...] [--widen-edges N]
                  [--metric agreement|success|time_s|cosine_distance|...]
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
This module parses the options into a `campaign.Plan` and is the command's shell (the output
folder, the cluster, the JSON line, the exit code); the campaign itself is app/tune/campaign.py.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dsteleop.app.cli.options import arbitration_config
from dsteleop.app.cli.world_options import add_world_arguments, world_overrides
from dsteleop.app.jsonable import jsonable
from dsteleop.app.outpaths import created_dir, output_dir
from dsteleop.errors import ConfigError, InputError

if TYPE_CHECKING:  # the command imports it when it runs (an instant --help)
    from dsteleop.app.tune.campaign import Plan


@dataclass(frozen=True)
class TuneCommand:
    """The `tune` command's settings.

    Attributes:
        plan: the campaign (app/tune/campaign.py).
        out: the output folder (holds the study's storage).
        address: the Ray cluster (None: a local one).
        workers: CPUs of a local cluster (None: every core).
        progress: draw the progress bars (None: on a terminal).
    """

    plan: Plan
    out: Path
    address: str | None = None
    workers: int | None = None
    progress: bool | None = None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from dsteleop.app.study import metric_table
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
        help="the mode's metric to optimise: agreement (default) or another of the metric "
        f"table's ({', '.join(n for n in metric_table.names() if n != 'agreement')}; docs/tune.md)",
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
    from dsteleop.app.tune.campaign import Plan

    plan = Plan(
        given=given,
        trials=None if args.trials_per_param is not None else int(args.trials or 40),
        trials_per_param=args.trials_per_param,
        widen_edges=int(args.widen_edges),
        resume=bool(args.resume),
        sessions_via=args.sessions_via,
        holdout_trajectories=int(args.holdout_trajectories),
        holdout_seed=args.holdout_seed,
        holdout_sessions=tuple(holdout_sessions),
        figures=not args.no_figures,
    )
    return TuneCommand(plan, Path(args.out), args.address, args.workers, args.progress)


def run(args: argparse.Namespace) -> int:
    t_start = time.monotonic()
    cmd = command(args)
    # A tuning run that fails leaves no empty --out behind (outpaths.created_dir).
    with created_dir(cmd.out) as out:
        return _run(cmd, out, t_start)


def _run(cmd: TuneCommand, out: Path, t_start: float) -> int:
    from dsteleop.app.tasks.cluster import RayExecutor
    from dsteleop.app.tune import campaign

    show = sys.stderr.isatty() if cmd.progress is None else bool(cmd.progress)
    summary = campaign.run(
        cmd.plan, out, lambda: RayExecutor(cmd.address, cmd.workers), show, t_start
    )
    json.dump(jsonable(campaign.brief(summary)), sys.stdout, separators=(",", ":"))
    sys.stdout.write("\n")
    error = campaign.failure(summary)
    if error is not None:
        raise InputError(error)
    return 0
