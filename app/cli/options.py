"""Options that several commands share, defined once.

    --param NAME=VALUE   an arbitration hyper-parameter (any field of ArbitrationConfig;
                         repeatable): run, serve, sim, replay
    --config FILE.json   a configuration file: an object of ArbitrationConfig fields, or
                         {"arbitration": {...}, "loop": {...}} (what `dsteleop tune` writes
                         as best.json); --param applies on top of it
    loop options         --source, --mode, --utensil, --seed, --goal-noise, --input-delay,
                         --rate, --lost-policy, --record, --record-video, --rerun,
                         --rerun-connect: run and serve

Values are checked here, so a bad one is one line naming it (exit 2) before anything opens.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app.loop import LoopConfig, LostPolicy
from dsteleop.app.rrd.target import DEFAULT_ADDR, RerunTarget
from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import ConfigError, InputError
from dsteleop.tracking.sources import SOURCE_GRAMMAR, SourceSpec, parse_source


def add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="FILE.json",
        help="arbitration (and loop) configuration file, e.g. a tuned best.json",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="arbitration hyper-parameter, e.g. kappa=8 (repeatable; over --config)",
    )


def read_config_file(path: Path | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(arbitration fields, loop fields) of a --config file (module docstring)."""
    if path is None:
        return {}, {}
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"--config: file not found: {path}") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"--config {path}: not a JSON file ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"--config {path}: expected a JSON object")
    if "arbitration" in data or "loop" in data:
        extra = sorted(set(data) - {"arbitration", "loop"} - {"objective", "note", "schema"})
        if extra:
            raise ConfigError(f"--config {path}: unknown section(s): {', '.join(extra)}")
        arb, loop = data.get("arbitration", {}), data.get("loop", {})
        if not isinstance(arb, dict) or not isinstance(loop, dict):
            raise ConfigError(f"--config {path}: sections must be JSON objects")
        return dict(arb), dict(loop)
    return dict(data), {}


def parse_params(items: list[str]) -> dict[str, Any]:
    """NAME=VALUE pairs as numbers (an integer where the field is one)."""
    ints = {f for f, v in ArbitrationConfig().to_dict().items() if isinstance(v, int)}
    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError(f"--param needs NAME=VALUE, got {item!r}")
        try:
            out[name] = int(value) if name in ints else float(value)
        except ValueError:
            raise ConfigError(f"--param {name}: not a number: {value!r}") from None
    return out


def arbitration_config(args: argparse.Namespace) -> tuple[ArbitrationConfig, dict[str, Any]]:
    """The arbitration config of --config and --param, and the loop fields of --config
    (checked here, whether or not the command uses them)."""
    arb, loop = read_config_file(args.config)
    try:
        cfg = ArbitrationConfig.from_dict({**arb, **parse_params(args.param)})
        LoopConfig.from_dict({**loop, "arbitration": cfg.to_dict()})
    except TypeError as exc:
        raise ConfigError(f"configuration: {exc}") from None
    return cfg, loop


def add_loop_options(parser: argparse.ArgumentParser, default_source: str) -> None:
    """Options shared by `run` and `serve`."""
    parser.add_argument("--source", default=default_source, help=f"{SOURCE_GRAMMAR}")
    parser.add_argument("--mode", default=None, help="DS, S, manual or autonomous (default DS)")
    parser.add_argument(
        "--utensil", default="spoon", help="utensil to pick (spoon, spatula, ladle)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of goal noise and demo operator")
    parser.add_argument(
        "--goal-noise", type=float, default=None, metavar="M", help="goal noise std-dev [m]"
    )
    parser.add_argument(
        "--input-delay", type=float, default=None, metavar="S", help="injected input delay [s]"
    )
    parser.add_argument("--rate", type=float, default=None, metavar="HZ", help="loop rate [Hz]")
    parser.add_argument(
        "--lost-policy",
        choices=[p.value for p in LostPolicy],
        default=None,
        help="what the robot does while the hand is lost (default halt)",
    )
    parser.add_argument(
        "--record", type=Path, default=None, metavar="DIR", help="record a session into DIR"
    )
    parser.add_argument(
        "--record-video",
        action="store_true",
        help="also record the camera frames (for replay --retrack)",
    )
    parser.add_argument(
        "--rerun",
        type=Path,
        default=None,
        metavar="FILE.rrd",
        help="write a Rerun recording while running (open with: rerun FILE.rrd)",
    )
    parser.add_argument(
        "--rerun-connect",
        nargs="?",
        const=DEFAULT_ADDR,
        default=None,
        metavar="ADDR",
        help=f"stream to a Rerun viewer you started (default {DEFAULT_ADDR})",
    )
    add_config_options(parser)


@dataclass(frozen=True)
class LoopOptions:
    """The loop options of `run` and `serve`, checked.

    Attributes:
        source: the hand source.
        loop: the loop configuration (mode, rate, lost policy, arbitration, ...).
        utensil: the utensil to pick.
        seed: seed of the goal noise and the demo operator.
        goal_noise_m: goal position noise [m] (None: the task's default).
        record: the session folder (run) or root (serve), or None.
        record_video: record the camera frames too.
        rerun: where a Rerun recording of the run goes, or None (docs/recordings.md).
    """

    source: SourceSpec
    loop: LoopConfig
    utensil: str = "spoon"
    seed: int = 0
    goal_noise_m: float | None = None
    record: Path | None = None
    record_video: bool = False
    rerun: RerunTarget | None = None

    @classmethod
    def of(cls, source: str = "demo", loop: LoopConfig | None = None, **kw: Any) -> LoopOptions:
        """Options for code (benches, tests): a source in the `--source` grammar."""
        return cls(parse_source(source), loop or LoopConfig(), **kw)


def loop_options(args: argparse.Namespace) -> LoopOptions:
    arb, loop_file = arbitration_config(args)
    flags: dict[str, Any] = {}
    if args.mode is not None:
        flags["mode"] = Mode.parse(args.mode)
    if args.rate is not None:
        flags["rate_hz"] = args.rate
    if args.input_delay is not None:
        flags["input_delay_s"] = args.input_delay
    if args.lost_policy is not None:
        flags["lost_policy"] = LostPolicy(args.lost_policy)
    base = LoopConfig.from_dict({**loop_file, "arbitration": arb.to_dict()})
    loop = base.replace(**flags)
    if args.goal_noise is not None and not args.goal_noise >= 0:
        raise ConfigError(f"--goal-noise must be >= 0, got {args.goal_noise}")
    if args.seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {args.seed}")
    return LoopOptions(
        source=parse_source(args.source),
        loop=loop,
        utensil=args.utensil,
        seed=args.seed,
        goal_noise_m=args.goal_noise,
        record=args.record,
        record_video=bool(args.record_video),
        rerun=(
            None
            if args.rerun is None and args.rerun_connect is None
            else RerunTarget(args.rerun, args.rerun_connect)
        ),
    )
