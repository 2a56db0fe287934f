"""The study's world on the command line, shared by `dsteleop sim` and `dsteleop tune`.

`add_world_arguments` adds the options that say which world the simulated people work in
(its impairments, docs/operator.md; the task's tolerances; the runs per person), and
`world_overrides` turns them into fields of `app.study.core.SimConfig`: the options not
given keep the study's defaults, so a `tune` run and a `sim` run with the same options score
the same world.
"""

from __future__ import annotations

import argparse
from typing import Any


def add_world_arguments(parser: argparse.ArgumentParser) -> None:
    a = parser.add_argument
    a(
        "--goal-sigma",
        type=float,
        default=None,
        metavar="M",
        help="robot goal position noise per axis [m] (default 0.02; docs/operator.md)",
    )
    a(
        "--delay",
        type=float,
        default=None,
        metavar="S",
        help="teleoperation delay each way [s] (default 0.2; docs/operator.md)",
    )
    a(
        "--depth-sigma",
        type=float,
        default=None,
        metavar="M",
        help="the operator's misjudgement of the robot's depth in its one camera view [m] "
        "(default 0.015; docs/operator.md)",
    )
    a(
        "--attempts",
        type=int,
        default=None,
        metavar="N",
        help="runs per simulated person and mode (default 3, the paper's three runs)",
    )
    a(
        "--success-radius",
        type=float,
        default=None,
        metavar="M",
        help="success radius R [m] (default 0.03)",
    )
    a(
        "--success-heading",
        type=float,
        default=None,
        metavar="RAD",
        help="success heading tolerance delta [rad] (default 0.35)",
    )


def world_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The `SimConfig` fields the world options set (ConfigError on a bad value)."""
    from dsteleop.app.operator.world import Impairments

    extra: dict[str, Any] = {}
    world: dict[str, float] = {}
    for arg, name in (
        ("goal_sigma", "goal_sigma_m"),
        ("delay", "delay_s"),
        ("depth_sigma", "depth_sigma_m"),
    ):
        v = getattr(args, arg)
        if v is not None:
            world[name] = float(v)
    if world:
        extra["world"] = Impairments().replace(**world)
    if args.attempts is not None:
        extra["attempts"] = args.attempts
    for arg, name in (
        ("success_radius", "success_radius_m"),
        ("success_heading", "success_heading_rad"),
    ):
        v = getattr(args, arg)
        if v is not None:
            extra[name] = float(v)
    return extra
