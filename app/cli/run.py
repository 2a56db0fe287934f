"""`dsteleop run`: the loop without a browser, live or headless; records sessions.

    dsteleop run --source demo --mode DS --utensil spoon --seed 0 --record DIR

Headless (the default for `demo` and `video:`) runs as fast as the machine allows on a
manual clock, deterministically; `--realtime` runs at the loop rate on the monotonic clock
(always for a webcam). Prints one JSON summary on stdout: outcome, ticks, simulated time,
wall time, timing.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any

from dsteleop.app.cli.options import (
    LoopOptions,
    add_loop_options,
    check_video_complete,
    loop_options,
)
from dsteleop.app.cli.signals import StopOnSignal
from dsteleop.app.link.config import link_config_path
from dsteleop.errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunCommand:
    """The `run` command's settings (logged at start).

    Attributes:
        options: the loop options shared with `serve`.
        realtime: run at the loop rate on the monotonic clock (live).
        max_seconds: stop after this much loop time [s].
        linked: the robot is at the far end of a link (`--robot zenoh:CONFIG`).
    """

    options: LoopOptions
    realtime: bool
    max_seconds: float
    linked: bool = False


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_loop_options(
        parser,
        default_source="demo",
        record_help="record the session into the folder DIR (created; must hold no session)",
    )
    parser.add_argument("--realtime", action="store_true", help="run at the loop rate (live)")
    parser.add_argument(
        "--max-seconds",
        type=float,
        default=150.0,
        help="stop after this loop time [s] (the task fails by timeout at 120 s)",
    )


def command(args: argparse.Namespace) -> RunCommand:
    options = loop_options(args)
    if not args.max_seconds > 0:
        raise ConfigError(f"--max-seconds must be > 0, got {args.max_seconds}")
    live = options.source.kind in ("webcam", "auto")
    linked = link_config_path(options.robot) is not None
    # A linked robot's physics keeps its own clock: the loop runs in real time.
    return RunCommand(
        options, bool(args.realtime or live or linked), float(args.max_seconds), linked
    )


def run(args: argparse.Namespace) -> int:
    cmd = command(args)
    from dsteleop.app.cli.compose import build

    opts = cmd.options
    log.info(
        "run: source %s, mode %s, realtime %s", opts.source, opts.loop.mode.value, cmd.realtime
    )
    built = build(opts, realtime=cmd.realtime)
    loop = built.loop
    max_ticks = int(cmd.max_seconds * opts.loop.rate_hz)
    t0 = time.perf_counter()
    session = None
    ended = ""  # why the hand's source ended, read before closing it (which ends any source)
    with StopOnSignal(loop, (signal.SIGTERM,)) as stopper:
        try:
            session = opts.record
            if session is None and opts.record_lerobot is not None:
                from dsteleop.app.lerobot.live import SESSIONS
                from dsteleop.app.session.writer import new_session_folder

                root = opts.record_lerobot / SESSIONS
                session = new_session_folder(root, loop.mode.value, opts.utensil)
            if session is not None:
                loop.start_recording(session, {"command": "run", "argv": sys.argv[1:]})
            if cmd.realtime:
                loop.run(max_ticks=max_ticks, until_outcome=True, until_finished=True)
            else:
                loop.run_headless(max_ticks)
            ended = loop.hand.end_reason if loop.hand.finished else ""
        finally:
            timing = loop.timing_summary()
            built.close()
    wall = time.perf_counter() - t0
    if built.video is not None:
        kept = "no session was recorded" if opts.record is None else f"the session is {opts.record}"
        check_video_complete(built.video, opts.allow_partial, kept)
    if stopper.received:
        stopped_by = stopper.received
    elif loop.outcome:
        stopped_by = "outcome"
    elif ended:
        stopped_by = ended
    else:
        stopped_by = "max-seconds"
    summary: dict[str, Any] = {
        "outcome": loop.outcome or "none",
        "stopped_by": stopped_by,
        "ticks": loop.tick_index,
        "loop_s": round(loop.tick_index / opts.loop.rate_hz, 3),
        "wall_s": round(wall, 3),
        "mode": loop.mode.value,
        "seed": opts.seed,
        "source": built.source.kind,
        "events": [f"{k}:{e}" for k, e in loop.events_log],
        "session": None if session is None else str(session),
        "timing": timing,
    }
    if cmd.linked:
        summary["robot_lost_ticks"] = loop.robot_lost_ticks
    if built.rerun is not None:
        summary["rerun"] = built.rerun.summary()
    if built.dataset is not None:
        summary["lerobot"] = built.dataset.summary()
    json.dump(summary, sys.stdout)
    sys.stdout.write("\n")
    return 0
