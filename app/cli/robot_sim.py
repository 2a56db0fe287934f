"""`dsteleop robot-sim --zenoh CONFIG`: the PyBullet robot at the far end of the Zenoh link.

    dsteleop robot-sim --zenoh link.json [--utensil spoon] [--seed 0] [--goal-noise M]
                       [--duration S]

Runs the KUKA iiwa with its hand in the kitchen as a separate process behind the link
(`app.link.far`): it takes the commands dsteleop publishes (dropping stale and out-of-order
ones), halts the arm when they stop for `command_timeout_s`, and publishes the measured palm
pose, joints and fingers at `rate_hz`. docs/link.md says how a real arm's driver does the
same. Stops on Ctrl-C or SIGTERM (or after `--duration`) and prints one JSON summary.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
from pathlib import Path

from dsteleop.app.cli.signals import StopOnSignal
from dsteleop.errors import ConfigError

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--zenoh", type=Path, required=True, metavar="CONFIG", help="the link's JSON file"
    )
    parser.add_argument("--utensil", default="spoon", help="the kitchen's utensil")
    parser.add_argument("--seed", type=int, default=0, help="the kitchen's seed")
    parser.add_argument(
        "--goal-noise",
        type=float,
        default=None,
        metavar="M",
        help="std-dev of the task's goal position noise [m] (default: the task's, 0.01)",
    )
    parser.add_argument(
        "--duration", type=float, default=None, metavar="S", help="stop after S seconds"
    )


class _Stop:
    def __init__(self) -> None:
        self.event = threading.Event()

    def stop(self) -> None:
        self.event.set()


def run(args: argparse.Namespace) -> int:
    from dsteleop.app.link.config import read_link_config
    from dsteleop.app.link.far import FarEnd

    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration must be > 0, got {args.duration}")
    config = read_link_config(args.zenoh)
    if args.goal_noise is not None and not 0.0 <= args.goal_noise <= 0.1:
        raise ConfigError(f"--goal-noise must be in [0, 0.1] m, got {args.goal_noise}")
    far = FarEnd(config, utensil=args.utensil, seed=args.seed, goal_noise_m=args.goal_noise)
    stop = _Stop()
    log.info(
        "robot-sim: %s at %g Hz, endpoints listen %s connect %s, commands on %s",
        far.env.robot.finger_names,
        config.rate_hz,
        list(config.far.listen),
        list(config.far.connect),
        config.topics.command_pose,
    )
    try:
        with StopOnSignal(stop):
            far.run(stop.event, args.duration)
    finally:
        summary = far.summary()
        far.close()
    json.dump(summary, sys.stdout)
    sys.stdout.write("\n")
    return 0
