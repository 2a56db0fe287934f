"""`dsteleop run`: the loop without a browser, live or headless; records sessions.

    dsteleop run --source demo --mode DS --utensil spoon --seed 0 --record DIR

Headless (the default for `demo` and `video:`) runs as fast as the machine allows on a
manual clock, deterministically; `--realtime` runs at the loop rate on the monotonic clock.
Prints one JSON summary on stdout: outcome, ticks, simulated time, wall time, timing.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

from dsteleop.app.loop import LoopConfig, LostPolicy
from dsteleop.app.setup import Setup, build
from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import DsteleopError


def add_loop_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by `run` and `serve`."""
    parser.add_argument("--mode", default="DS", help="DS, S, manual or autonomous (default DS)")
    parser.add_argument(
        "--utensil", default="spoon", help="utensil to pick (spoon, spatula, ladle)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of goal noise and demo operator")
    parser.add_argument(
        "--goal-noise", type=float, default=None, metavar="M", help="goal noise std-dev [m]"
    )
    parser.add_argument(
        "--input-delay", type=float, default=0.0, metavar="S", help="injected input delay [s]"
    )
    parser.add_argument("--rate", type=float, default=30.0, metavar="HZ", help="loop rate [Hz]")
    parser.add_argument("--lost-policy", choices=[p.value for p in LostPolicy], default="halt")
    parser.add_argument(
        "--record", type=Path, default=None, metavar="DIR", help="record a session into DIR"
    )
    parser.add_argument(
        "--record-video",
        action="store_true",
        help="also record the camera frames (for replay --retrack)",
    )


def loop_config(args: argparse.Namespace) -> LoopConfig:
    try:
        mode = Mode.parse(args.mode)
    except ValueError as exc:
        raise DsteleopError(str(exc)) from exc
    if args.goal_noise is not None and not args.goal_noise >= 0:
        raise DsteleopError(f"--goal-noise must be >= 0, got {args.goal_noise}")
    return LoopConfig(
        rate_hz=args.rate,
        mode=mode,
        input_delay_s=args.input_delay,
        lost_policy=LostPolicy(args.lost_policy),
        arbitration=ArbitrationConfig(),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", default="demo", help="demo, webcam:N, video:PATH or auto")
    add_loop_arguments(parser)
    parser.add_argument("--realtime", action="store_true", help="run at the loop rate (live)")
    parser.add_argument(
        "--max-seconds", type=float, default=120.0, help="stop after this loop time [s]"
    )


def run(args: argparse.Namespace) -> int:
    cfg = loop_config(args)
    if args.max_seconds <= 0:
        raise DsteleopError(f"--max-seconds must be > 0, got {args.max_seconds}")
    realtime = bool(args.realtime or str(args.source).startswith("webcam") or args.source == "auto")
    history_dir = args.record.parent if args.record is not None else None
    built = build(
        Setup(
            source=args.source,
            loop=cfg,
            utensil=args.utensil,
            seed=args.seed,
            goal_noise_m=args.goal_noise,
            realtime=realtime,
            history_dir=history_dir,
            record_video=bool(args.record_video),
        )
    )
    loop = built.loop
    max_ticks = int(args.max_seconds * cfg.rate_hz)
    signal.signal(signal.SIGTERM, lambda *_: loop.stop())
    t0 = time.perf_counter()
    try:
        if args.record is not None:
            loop.start_recording(args.record, {"command": "run", "argv": sys.argv[1:]})
        if realtime:
            loop.run(max_ticks=max_ticks, until_outcome=True)
        else:
            run_headless(loop, built.demo, max_ticks)
    finally:
        loop.close()
    wall = time.perf_counter() - t0
    summary: dict[str, Any] = {
        "outcome": loop.outcome or "none",
        "ticks": loop.tick_index,
        "loop_s": round(loop.tick_index / cfg.rate_hz, 3),
        "wall_s": round(wall, 3),
        "mode": loop.mode.value,
        "source": built.source_kind,
        "events": [f"{k}:{e}" for k, e in loop.events_log],
        "session": None if args.record is None else str(args.record),
        "timing": loop.rate.summary(),
    }
    json.dump(summary, sys.stdout)
    sys.stdout.write("\n")
    return 0


def run_headless(loop: Any, demo: Any, max_ticks: int, tail_s: float = 0.5) -> None:
    """Tick on the manual clock as fast as possible until an outcome, the end of a file
    source (plus `tail_s`, so the halt shows in the record), or `max_ticks`."""
    dt = loop.config.dt_s
    end_at: float | None = None
    for k in range(max_ticks):
        t = k * dt
        loop.clock.sleep_until(t)
        snap = loop.tick(t)
        if demo is not None:
            demo.watch(snap)
        if loop.outcome:
            break
        if end_at is None and getattr(loop.hand, "finished", False):
            end_at = t + tail_s
        if end_at is not None and t >= end_at:
            break
