"""The study's world on the command line, shared by `dsteleop sim` and `dsteleop tune`.

`add_world_arguments` adds the options that say which world the simulated people work in
(its impairments, docs/operator.md; the task's tolerances; the runs per person), and
`world_overrides` turns them into fields of `app.study.planar.SimConfig`: the options not
given keep the study's defaults, so a `tune` run and a `sim` run with the same options score
the same world.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from dsteleop.errors import ConfigError

#: The worlds `--world` names: the default (one grasp, the robot's goal position noisy), the
#: disagreement world (two right grasps) and the objects world (the robot infers which of K
#: objects the person wants; docs/operator.md).
WORLDS: tuple[str, ...] = ("wrong-goal", "disagreement", "objects")

#: The objects world's options: option (its `args` name) -> field of `Objects`.
OBJECT_OPTIONS: dict[str, str] = {
    "objects": "count",
    "object_spacing": "spacing_m",
    "perception_depth": "perception_depth_m",
    "perception_lateral": "perception_lateral_m",
    "perception_heading": "perception_heading_rad",
    "change_share": "change_share",
    "change_at": "change_at_s",
}


def add_world_arguments(parser: argparse.ArgumentParser) -> None:
    a = parser.add_argument
    a(
        "--world",
        default=None,
        help="wrong-goal (default: one grasp, the robot's goal position noisy), disagreement "
        "(two right grasps, top and side; the robot goes to one, each person prefers one; "
        "goal noise 0 unless --goal-sigma) or objects (K objects, the person wants one and may "
        "change its mind, the robot infers which and perceives them with its own error; goal "
        "noise 0 unless --goal-sigma; docs/operator.md)",
    )
    a(
        "--robot-grasp",
        default=None,
        metavar="NAME",
        help="disagreement world: the grasp the robot goes to, top (default) or side",
    )
    a(
        "--prefer-robot-share",
        type=float,
        default=None,
        metavar="P",
        help="disagreement world: the share of people who prefer the robot's grasp (0.5)",
    )
    a(
        "--adaptability",
        default=None,
        metavar="LO,HI",
        help="disagreement world: each person's chance of switching to the robot's grasp at a "
        "resistance pause is drawn from U(LO, HI) (default 0,1)",
    )
    a(
        "--grasp-separation",
        type=float,
        default=None,
        metavar="RAD",
        help="disagreement world: the side grasp's heading from the top grasp's (default pi/2)",
    )
    a(
        "--objects",
        type=int,
        default=None,
        metavar="K",
        help="objects world: the number of objects, 1-9 (default 3)",
    )
    a(
        "--object-spacing",
        type=float,
        default=None,
        metavar="M",
        help="objects world: the distance between neighbouring objects [m] (default 0.08)",
    )
    a(
        "--perception-depth",
        type=float,
        default=None,
        metavar="M",
        help="objects world: the robot's perception error along its camera's view [m] (0.02)",
    )
    a(
        "--perception-lateral",
        type=float,
        default=None,
        metavar="M",
        help="objects world: the robot's perception error across its camera's view [m] (0.005)",
    )
    a(
        "--perception-heading",
        type=float,
        default=None,
        metavar="RAD",
        help="objects world: the robot's perception error of each object's heading (0.05)",
    )
    a(
        "--change-share",
        type=float,
        default=None,
        metavar="P",
        help="objects world: the share of runs in which the person changes its mind (0.2)",
    )
    a(
        "--change-at",
        default=None,
        metavar="LO,HI",
        help="objects world: the time of a change of mind is drawn from U(LO, HI) [s] (1.5,3)",
    )
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
    from dsteleop.app.study.grasps import Grasps
    from dsteleop.app.study.objects import Objects

    extra: dict[str, Any] = {}
    world: dict[str, float] = {}
    kind = "wrong-goal" if args.world is None else str(args.world)
    if kind not in WORLDS:
        raise ConfigError(f"unknown world {kind!r} (choose from {', '.join(WORLDS)})")
    grasp_options = {
        "robot_grasp": args.robot_grasp,
        "prefer_robot_share": args.prefer_robot_share,
        "adaptability": args.adaptability,
        "separation_rad": args.grasp_separation,
    }
    given = {k: v for k, v in grasp_options.items() if v is not None}
    if kind == "disagreement":
        if "adaptability" in given:
            given["adaptability"] = _interval(str(given["adaptability"]), "--adaptability")
        extra["grasps"] = Grasps(**given)
        world["goal_sigma_m"] = 0.0  # both agents are right, unless --goal-sigma says not
    elif given:
        option = "--" + sorted(given)[0].replace("_rad", "").replace("_", "-")
        option = option.replace("separation", "grasp-separation")
        raise ConfigError(f"{option} goes with --world disagreement")
    options = [a for a in OBJECT_OPTIONS if getattr(args, a, None) is not None]
    objects = {OBJECT_OPTIONS[a]: getattr(args, a) for a in options}
    if kind == "objects":
        if "change_at_s" in objects:
            objects["change_at_s"] = _interval(str(objects["change_at_s"]), "--change-at")
        extra["objects"] = Objects(**objects)
        world["goal_sigma_m"] = 0.0  # the robot's known error is its perception's
    elif options:
        raise ConfigError(f"--{options[0].replace('_', '-')} goes with --world objects")
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


def _interval(text: str, option: str) -> tuple[float, float]:
    """`LO,HI` as two floats (ConfigError naming `option` otherwise)."""
    parts = text.split(",")
    try:
        lo, hi = (float(p) for p in parts)
    except ValueError:
        raise ConfigError(f"{option} must be LO,HI (two numbers), got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ConfigError(f"{option} must be finite, got {text!r}")
    return lo, hi
