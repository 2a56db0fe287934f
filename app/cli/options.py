"""Options that several commands share, defined once.

    --param NAME=VALUE   an arbitration hyper-parameter (any field of ArbitrationConfig;
                         repeatable): run, serve, sim, replay
    --config FILE.json   a configuration file: an object of ArbitrationConfig fields, or
                         {"arbitration": {...}, "loop": {...}} (what `dsteleop tune` writes
                         as best.json, with its "objective", "world", "note" and
                         "schema" as a record of the tuning, not applied: a command's own
                         world options choose its world); --param applies on top of it
    loop options         --source, --mode, --goal, --utensil, --change-mind, --seed, --goal-noise,
                         --input-delay,
                         --rate, --lost-policy, --history, --record, and every output's own
                         (app/outputs: --record-video, --record-lerobot, --rerun,
                         --rerun-connect): run and serve

Values are checked here, so a bad one is one line naming it (exit 2) before anything opens.
Bounds that are not the loop's own domain, and why:

    --rate          RATE_RANGE_HZ (10-120 Hz): the simulated world advances 1/rate s per tick
                    (robot.arm.RobotConfig.control_dt_s), its physics in steps of at most
                    1/90 s; below 10 Hz one tick's command moves the palm further than the
                    arm's controllers were made for, and above 120 Hz no machine this runs on
                    keeps up (a tick takes 2-4 ms, and a browser and tracking share the cores)
    --goal-noise    at most MAX_GOAL_NOISE_M (0.1 m): beyond it the goal the robot knows lies
                    typically further from the true one than the bin's inner half-width
                    (0.18 m), so the robot works against any operator
    --input-delay   at most MAX_INPUT_DELAY_S (1 s): each hand sample reaches the loop that
                    much later, so nothing moves before it; teleoperation studies go up to
                    about 1 s (beyond it operators move and wait, which the loop does not
                    model), and a delay near the time limit only makes trials time out
"""

from __future__ import annotations

import argparse
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app import outputs, sources
from dsteleop.app.compose.options import LoopOptions, RobotSpec
from dsteleop.app.jsonable import read_json
from dsteleop.app.loop import LoopConfig, LostPolicy
from dsteleop.app.outpaths import check_output_file, output_dir, output_file
from dsteleop.arbitration import ArbitrationConfig, Mode, registered
from dsteleop.errors import ConfigError, InputError
from dsteleop.tracking.sources import (
    ROTATIONS_DEG,
    VideoFileSource,
    check_rotation,
)

log = logging.getLogger(__name__)

#: The loop rates `--rate` accepts [Hz] (module docstring).
RATE_RANGE_HZ = (10.0, 120.0)
#: The largest `--goal-noise` [m] (module docstring).
MAX_GOAL_NOISE_M = 0.1
#: The largest `--input-delay` [s] (module docstring).
MAX_INPUT_DELAY_S = 1.0


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


def read_config_file(
    path: Path | None, option: str = "--config", sections: tuple[str, ...] = ()
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """(arbitration fields, loop fields, the `sections`) of a --config file (module
    docstring), read once; `option` names the option the file came from in the one-line
    errors; `sections` are more sections the command reads itself (the study's per-mode
    `modes`), handed back as the file has them."""
    if path is None:
        return {}, {}, {}
    data = read_json(path, option)
    if not isinstance(data, dict):
        raise ConfigError(f"{option} {path}: expected a JSON object")
    if "arbitration" in data or "loop" in data:
        extra = sorted(
            set(data)
            - {"arbitration", "loop", *sections}
            - {"objective", "world", "note", "schema"}
        )
        if extra:
            raise ConfigError(f"{option} {path}: unknown section(s): {', '.join(extra)}")
        arb, loop = data.get("arbitration", {}), data.get("loop", {})
        if not isinstance(arb, dict) or not isinstance(loop, dict):
            raise ConfigError(f"{option} {path}: sections must be JSON objects")
        return dict(arb), dict(loop), {k: data[k] for k in sections if k in data}
    return dict(data), {}, {}


def parse_params(items: list[str]) -> dict[str, Any]:
    """NAME=VALUE pairs as numbers (an integer where the field is one; the word as given
    where the field is a word, `human_reference=leaky`: the configuration checks it)."""
    ints = {f for f, v in ArbitrationConfig().to_dict().items() if isinstance(v, int)}
    words = ArbitrationConfig.word_fields()
    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError(f"--param needs NAME=VALUE, got {item!r}")
        if name in words:
            out[name] = value.strip()
            continue
        try:
            number = float(value)
        except ValueError:
            raise ConfigError(f"--param {name}: not a number: {value!r}") from None
        if name in ints:
            if not (math.isfinite(number) and number == int(number)):
                raise ConfigError(f"--param {name}: must be a whole number, got {value.strip()}")
            out[name] = int(number)
        else:
            out[name] = number
    return out


@dataclass(frozen=True)
class Configuration:
    """A configuration file with `--param` on top, parsed once (`configuration`).

    Attributes:
        arbitration: the arbitration configuration.
        loop: the file's loop section over the defaults, with `arbitration`.
        loop_fields: the loop fields the file set (a default it repeats counts as set).
        file_fields: the file's arbitration fields as written (before `--param`).
        sections: the file's sections that the command reads itself (`configuration`'s
            `sections`), as written.
    """

    arbitration: ArbitrationConfig
    loop: LoopConfig
    loop_fields: frozenset[str]
    file_fields: dict[str, Any]
    sections: dict[str, Any]


def arbitration_config(args: argparse.Namespace) -> ArbitrationConfig:
    """The arbitration config of --config and --param (the file's loop section checked
    too, whether or not the command uses it)."""
    return configuration(args.config, args.param).arbitration


def configuration(
    path: Path | None, params: list[str], option: str = "--config", sections: tuple[str, ...] = ()
) -> Configuration:
    """The configuration of the file `path` (`read_config_file`; None: the defaults) with
    the `--param` items `params` on top; `option` names the file's option in the errors;
    `sections` as `read_config_file`'s."""
    arb, loop, extra = read_config_file(path, option, sections)
    try:
        cfg = ArbitrationConfig.from_dict({**arb, **parse_params(params)})
        loop_cfg = LoopConfig.from_dict(loop, arbitration=cfg)
    except TypeError as exc:
        where = "configuration" if option == "--config" else f"{option} {path}"
        raise ConfigError(f"{where}: {exc}") from None
    except ConfigError as exc:
        if option == "--config":
            raise
        raise ConfigError(f"{option} {path}: {exc}") from None
    return Configuration(cfg, loop_cfg, frozenset(loop), dict(arb), extra)


def config_from_file(
    path: Path | None, params: list[str], option: str = "--config", sections: tuple[str, ...] = ()
) -> ArbitrationConfig:
    """The arbitration configuration of `configuration(path, params, option, sections)`."""
    return configuration(path, params, option, sections).arbitration


def add_video_options(parser: argparse.ArgumentParser) -> None:
    """`--rotate` and `--allow-partial`: how a video file is read (track, run, serve, replay)."""
    parser.add_argument(
        "--rotate",
        type=int,
        choices=ROTATIONS_DEG,
        default=None,
        metavar="DEG",
        help="turn video (or camera) frames 0, 90, 180 or 270 degrees clockwise "
        "(default: the rotation the video's container asks for)",
    )
    parser.add_argument(
        "--allow-partial",
        action="store_true",
        help="accept a video that ends before the frame count it declares (truncated)",
    )


def check_video_complete(source: VideoFileSource, allow_partial: bool, kept: str) -> None:
    """After reading a video: one line and an error if it was cut short, a warning if that
    was allowed (`--allow-partial`).

    Args:
        source: the video, read to its end.
        allow_partial: accept a partial video.
        kept: what was kept of it, for the message (e.g. where the tracked frames are).

    Raises:
        InputError: the video was partial and `allow_partial` is False.
    """
    if not source.partial:
        return
    if not allow_partial:
        raise InputError(
            f"{source.path}: {source.end_note()} (truncated or partly unreadable); {kept}; "
            "--allow-partial accepts a partial video"
        )
    log.warning("%s: %s (truncated); accepted (--allow-partial)", source.path, source.end_note())


def add_loop_options(
    parser: argparse.ArgumentParser, default_source: str, record_help: str
) -> None:
    """Options shared by `run` and `serve` (`record_help`: what `--record DIR` means there)."""
    parser.add_argument("--source", default=default_source, help=sources.grammar())
    parser.add_argument(
        "--mode",
        default=None,
        help=f"the arbitration mode: {', '.join(m.value for m in registered())} (default DS)",
    )
    parser.add_argument(
        "--robot",
        default="iiwa",
        metavar="NAME|FILE",
        help="the robot: a shipped description (iiwa, panda), a robot description file "
        "(.toml, docs/robots.md), or zenoh:CONFIG, an arm at the far end of a Zenoh link "
        "(docs/link.md); default iiwa",
    )
    parser.add_argument(
        "--goal",
        default=None,
        metavar="infer|UTENSIL",
        help="what the robot is told: a utensil (spoon, spatula, ladle), or infer: it is told "
        "none and infers the person's from the hand's motion among the utensils in the holder "
        "(docs/METHOD.md §10); default: told the --utensil",
    )
    parser.add_argument(
        "--utensil",
        default=None,
        help="the utensil the person picks (spoon, spatula, ladle; default spoon): the demo "
        "person's; with a told --goal it must be that one",
    )
    parser.add_argument(
        "--change-mind",
        default=None,
        metavar="UTENSIL:S",
        help="the demo person turns to UTENSIL S seconds into each trial, while it still "
        "reaches (with --goal infer; docs/operator.md)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of goal noise and demo operator")
    parser.add_argument(
        "--goal-noise",
        type=float,
        default=None,
        metavar="M",
        help=f"goal noise std-dev [m], 0-{MAX_GOAL_NOISE_M:g}",
    )
    parser.add_argument(
        "--input-delay",
        type=float,
        default=None,
        metavar="S",
        help=f"injected input delay [s], 0-{MAX_INPUT_DELAY_S:g}",
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        metavar="HZ",
        help=f"loop rate [Hz], {RATE_RANGE_HZ[0]:g}-{RATE_RANGE_HZ[1]:g} (default 30); the "
        "simulated world advances 1/HZ s per tick",
    )
    parser.add_argument(
        "--lost-policy",
        choices=[p.value for p in LostPolicy],
        default=None,
        help="what the robot does while the hand is lost (default halt)",
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="S",
        help="a trial without an outcome after S seconds fails (timeout; default 120)",
    )
    parser.add_argument(
        "--reset-after",
        type=float,
        default=None,
        metavar="S",
        help="serve: reset the task S seconds after each outcome, for the next trial "
        "(0: never; default 4); run stops at its first outcome and refuses it",
    )
    parser.add_argument(
        "--history",
        type=output_file,
        default=None,
        metavar="FILE",
        help="the operator's previous attempts (eq 6): read from FILE at start, each finished "
        "segment appended to it (default: none, an empty history, so a run depends only on "
        "its options and seed)",
    )
    parser.add_argument(
        "--loop-video",
        action="store_true",
        help="play a video source again from the start when it ends",
    )
    parser.add_argument("--record", type=output_dir, default=None, metavar="DIR", help=record_help)
    outputs.add_arguments(parser)  # every registered output's options (app/outputs)
    add_video_options(parser)
    add_config_options(parser)


def loop_options(args: argparse.Namespace, reset_after_s: float = 0.0) -> LoopOptions:
    """The checked loop options (`reset_after_s`: the command's default for --reset-after)."""
    check_loop_bounds(args.rate, args.goal_noise, args.input_delay)  # the flags, named
    config = configuration(args.config, args.param)
    flags: dict[str, Any] = {}
    if args.mode is not None:
        flags["mode"] = Mode.parse(args.mode)
    if args.rate is not None:
        flags["rate_hz"] = args.rate
    if args.input_delay is not None:
        flags["input_delay_s"] = args.input_delay
    if args.lost_policy is not None:
        flags["lost_policy"] = LostPolicy(args.lost_policy)
    if args.reset_after is not None:
        flags["reset_after_s"] = args.reset_after
    elif "reset_after_s" not in config.loop_fields:
        flags["reset_after_s"] = reset_after_s
    limit = args.time_limit
    if limit is not None and not (math.isfinite(limit) and limit > 0):
        raise ConfigError(f"--time-limit must be > 0 seconds, got {limit}")
    loop = config.loop.replace(**flags)
    # Rate and delay as the loop will run (a --config file's loop section may set them too).
    check_loop_bounds(loop.rate_hz, args.goal_noise, loop.input_delay_s)
    if args.seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {args.seed}")
    source = sources.parse(args.source)
    history = check_history_path(args.history)
    robot = check_robot(args.robot)
    # Each output's settings, checked before a camera or the robot is opened; an output that
    # reads the camera's frames (a dataset) has them recorded when the source has any.
    asked = outputs.parse(args, source, pixels=sources.kind(source.kind).pixels)
    return LoopOptions(
        source=source,
        loop=loop,
        utensil=args.utensil or "",
        goal=args.goal or "",
        change_mind=parse_change_mind(args.change_mind),
        robot=robot,
        seed=args.seed,
        goal_noise_m=args.goal_noise,
        record=args.record,
        outputs=asked,
        loop_video=bool(args.loop_video),
        rotate=check_rotation(args.rotate),
        allow_partial=bool(args.allow_partial),
        time_limit_s=limit,
        history=history,
        input_delay_given=args.input_delay is not None or "input_delay_s" in config.loop_fields,
    )


def parse_change_mind(text: str | None) -> tuple[str, float] | None:
    """`--change-mind UTENSIL:S` as (utensil, seconds); None when not given (the rest is
    checked with the other options, `compose.options.check_change_mind`).

    Raises:
        ConfigError: not UTENSIL:S with S a number (one line).
    """
    if text is None:
        return None
    name, sep, at = text.partition(":")
    try:
        seconds = float(at)
    except ValueError:
        seconds = math.nan
    if not sep or not name or not math.isfinite(seconds):
        raise ConfigError(f"--change-mind needs UTENSIL:S (e.g. spatula:1.5), got {text!r}")
    return name.strip(), seconds


def check_robot(robot: str) -> RobotSpec:
    """`--robot NAME|FILE` names a valid robot description (read and checked against its
    URDF now, before anything runs or records); `--robot zenoh:CONFIG` a valid link
    configuration file and its robot's description: the robot, read once
    (`RobotSpec.parse`, which raises the one-line errors). Its arm must reach every pose of
    the task where the scene stands for it (`robot.reach.require_reachable`: else one line
    naming the pose, the error and the fix).
    """
    from dsteleop.robot.reach import require_reachable

    spec = RobotSpec.parse(robot)
    require_reachable(spec.description)
    return spec


def check_loop_bounds(
    rate_hz: float | None, goal_noise_m: float | None, input_delay_s: float | None
) -> None:
    """`--rate`, `--goal-noise` and `--input-delay` within their documented bounds (module
    docstring); None: not given.

    Raises:
        ConfigError: one line naming the option, its bound and why.
    """
    lo, hi = RATE_RANGE_HZ
    if rate_hz is not None and not (math.isfinite(rate_hz) and lo <= rate_hz <= hi):
        raise ConfigError(
            f"--rate must be in {lo:g}-{hi:g} Hz, got {rate_hz:g}: the simulated world advances "
            "1/rate s per tick, and outside this range either the arm's controllers or the "
            "machine cannot keep up (docs/ARCHITECTURE.md, Runs you can trust)"
        )
    if goal_noise_m is not None and not (
        math.isfinite(goal_noise_m) and 0 <= goal_noise_m <= MAX_GOAL_NOISE_M
    ):
        raise ConfigError(
            f"--goal-noise must be in 0-{MAX_GOAL_NOISE_M:g} m, got {goal_noise_m:g}: beyond "
            "it the robot's goal is typically further off than the bin is wide"
        )
    if input_delay_s is not None and not (
        math.isfinite(input_delay_s) and 0 <= input_delay_s <= MAX_INPUT_DELAY_S
    ):
        raise ConfigError(
            f"--input-delay must be in 0-{MAX_INPUT_DELAY_S:g} s, got {input_delay_s:g}: the "
            "robot gets no hand input before the delay has passed, so a longer one leaves "
            "it standing until the trial times out"
        )


def check_history_path(path: Path | None) -> Path | None:
    """`--history FILE`: a file (or a new one) that can be written (`outpaths`): it is first
    written at the first finished segment, mid-trial.

    Raises:
        InputError: it names a folder, its folder does not exist or cannot be written.
    """
    return None if path is None else check_output_file(path, "--history")
