"""`dsteleop robot-sim --zenoh CONFIG`: the PyBullet robot at the far end of the Zenoh link.

    dsteleop robot-sim --zenoh link.json [--utensil spoon] [--duration S]

Runs the link configuration's robot (`"robot"`, a description: the KUKA iiwa with its hand
by default) in a PyBullet world of its own as a separate process behind the link
(`app.link.far`), a robot driver and nothing else: the task is judged by dsteleop at the near
end, through a twin of this robot (docs/link.md). It takes the commands dsteleop publishes
(dropping stale and out-of-order ones), halts the arm when they stop for `command_timeout_s`,
and publishes the measured palm pose, joints and fingers at `rate_hz`. docs/link.md says
how a real arm's driver does the same. Stops on Ctrl-C or SIGTERM (or after `--duration`)
and prints one JSON summary.
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
    parser.add_argument(
        "--utensil", default="spoon", help="the utensil in the arm's world (the scene before it)"
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
    far = FarEnd(config, utensil=args.utensil)
    stop = _Stop()
    log.info(
        "robot-sim: %s of %s at %g Hz, endpoints listen %s connect %s, commands on %s",
        far.robot.finger_names,
        far.robot.name,
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
