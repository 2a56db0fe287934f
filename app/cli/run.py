"""`dsteleop run`: the loop without a browser, live or headless; records sessions.

    dsteleop run --source demo --mode DS --utensil spoon --seed 0 --record DIR

Headless (the default for `demo` and `video:`) runs as fast as the machine allows on a
manual clock, deterministically; `--realtime` runs at the loop rate on the monotonic clock
(always for a webcam). Prints one JSON summary on stdout: outcome, ticks, simulated time,
wall time, timing.

A robot lost (no state, `ports.ROBOT_STALE_S`) for longer than `--robot-lost-s` (default 5 s),
or still lost when the trial reaches its time limit without an outcome, ends the run: the
summary is printed (`stopped_by: robot-lost`), the recording is closed complete, and the
command exits with code 3 and a one-line reason (`RobotLostError`), so a script can tell a
dead robot from a normal run. The loop itself halts the robot smoothly as soon as it is lost.

`run` is one trial: it stops at the first outcome, so `--reset-after` (a loop option shared
with `serve`) is refused unless 0.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any

from dsteleop.app import sources
from dsteleop.app.cli.options import add_loop_options, check_video_complete, loop_options
from dsteleop.app.cli.signals import StopOnSignal
from dsteleop.app.compose.options import LoopOptions
from dsteleop.app.outputs import session_root
from dsteleop.errors import ConfigError, RobotLostError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunCommand:
    """The `run` command's settings (logged at start).

    Attributes:
        options: the loop options shared with `serve`.
        realtime: run at the loop rate on the monotonic clock (live).
        max_seconds: stop after this much loop time [s].
        linked: the robot is at the far end of a link (`--robot zenoh:CONFIG`).
        robot_lost_s: a robot lost for longer than this ends the run (exit code 3) [s].
    """

    options: LoopOptions
    realtime: bool
    max_seconds: float
    linked: bool = False
    robot_lost_s: float = 5.0


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
    parser.add_argument(
        "--robot-lost-s",
        type=float,
        default=5.0,
        metavar="S",
        help="a robot lost (no state) for longer than S seconds ends the run with exit code 3 "
        "(default 5; a linked robot whose far end died)",
    )


def command(args: argparse.Namespace) -> RunCommand:
    options = loop_options(args)
    reset_after_s = options.loop.reset_after_s
    if reset_after_s > 0:  # no next trial follows to reset for
        given = "--reset-after" if args.reset_after else f"--config {args.config}: reset_after_s"
        raise ConfigError(
            f"{given} {reset_after_s:g}: run stops at its first outcome, so no next trial "
            "follows; serve runs trial after trial (its --reset-after), or run again with "
            "another --seed"
        )
    if not args.max_seconds > 0:
        raise ConfigError(f"--max-seconds must be > 0, got {args.max_seconds}")
    if not (math.isfinite(args.robot_lost_s) and args.robot_lost_s > 0):
        raise ConfigError(f"--robot-lost-s must be > 0 seconds, got {args.robot_lost_s}")
    live = sources.kind(options.source.kind).live  # a camera: only in real time
    linked = options.robot.linked
    # A linked robot's physics keeps its own clock: the loop runs in real time.
    return RunCommand(
        options,
        bool(args.realtime or live or linked),
        float(args.max_seconds),
        linked,
        float(args.robot_lost_s),
    )


def run(args: argparse.Namespace) -> int:
    cmd = command(args)
    from dsteleop.app.compose.root import build

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
            root = session_root(opts.outputs)  # an output that needs sessions (a dataset)
            if session is None and root is not None:
                from dsteleop.app.session.writer import new_session_folder

                session = new_session_folder(root, loop.mode.value, opts.utensil)
            if session is not None:
                loop.start_recording(session, {"command": "run", "argv": sys.argv[1:]})
            if cmd.realtime:
                loop.run(
                    max_ticks=max_ticks,
                    until_outcome=True,
                    until_finished=True,
                    robot_lost_limit_s=cmd.robot_lost_s,
                    time_limit_s=_time_limit_s(opts, loop.task.describe()),
                )
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
    elif loop.robot_lost_end:
        stopped_by = "robot-lost"
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
        # stray messages the near end dropped on the state topics (ZenohRobot.dropped)
        summary["dropped_stray"] = getattr(loop.robot, "dropped", {})
    summary.update(built.summaries())  # what each output wrote, by its name
    json.dump(summary, sys.stdout)
    sys.stdout.write("\n")
    if loop.robot_lost_end and not stopper.received:
        sys.stdout.flush()
        raise RobotLostError(loop.robot_lost_end)
    return 0


def _time_limit_s(opts: LoopOptions, task: dict[str, Any]) -> float | None:
    """The trial's time limit [s]: `--time-limit`, else the task's own (None: it has none)."""
    if opts.time_limit_s is not None:
        return opts.time_limit_s
    own = (task.get("task") or {}).get("timeout_s")
    return None if own is None else float(own)
