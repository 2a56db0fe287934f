"""`dsteleop robot check FILE|NAME`: does a robot description do the kitchen task?

    dsteleop robot check panda
    dsteleop robot check ./my_arm.toml --json

Reports, for a description (`robot.check`): where the task's scene stands (its placement),
each task pose's reachability at its grasp orientation (IK error in mm and deg), the palm's
steady-state error at a still pose, the gripper closing on each utensil and lifting it in the
PyBullet world, the derived values (joint limits, home, workspace, reach) and every problem
as one line with its fix. Exit code 0 when every check passes, 1 when one fails, 2 for bad
input (a description that does not load: one line). `--json` prints one JSON object instead.
Takes about a minute (each check runs the simulation; docs/robots.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from dsteleop.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="robot_command", metavar="ACTION")
    check = sub.add_parser(
        "check",
        help="report a description's reach, steady state and grasp, and every problem",
        description="report a description's task placement, reach of every task pose, "
        "steady-state error, gripper closing on each utensil, derived values and problems "
        "(exit 0: every check passes, 1: one fails, 2: bad input)",
    )
    check.add_argument("robot", metavar="FILE|NAME", help="a description file or shipped name")
    check.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    if getattr(args, "robot_command", None) != "check":
        raise ConfigError("robot: say what to do: dsteleop robot check FILE|NAME")
    from dsteleop.robot.check import check
    from dsteleop.robot.description import load_description

    if not args.verbose:  # the stalls of an arm out of reach are the report's, not the log's
        logging.getLogger("dsteleop.robot.arm").setLevel(logging.ERROR)
    report = check(load_description(args.robot, given_by="robot check"))
    if args.json:
        json.dump(report.to_dict(), sys.stdout)
        sys.stdout.write("\n")
    else:
        sys.stdout.write("\n".join(report.lines()) + "\n")
    return 0 if report.ok else 1
