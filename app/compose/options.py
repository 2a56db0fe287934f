"""What a loop is built from: the user's choices, parsed and checked (by the command line,
`app/cli/options.py`, or by code: benches, tests), as one typed value handed to `build`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dsteleop.app import sources
from dsteleop.app.link.config import LinkConfig, link_config_path, read_link_config
from dsteleop.app.loop import LoopConfig
from dsteleop.errors import ConfigError
from dsteleop.robot.description import RobotDescription, load_description
from dsteleop.robot.task import INFER
from dsteleop.tracking.sources import SourceSpec

#: A live session (`serve`) resets the task this long after each outcome, for the next
#: trial [s] (`--reset-after`).
RESET_AFTER_S = 4.0


@dataclass(frozen=True)
class RobotSpec:
    """`--robot NAME|FILE|zenoh:CONFIG`, read once: the robot's description (checked against
    its URDF), and the link's configuration when the robot is at the far end of a Zenoh link
    (docs/link.md).

    Attributes:
        description: the robot's description (a linked robot's: the one its link names).
        link: the link's configuration (its fingers and limits filled in from the
            description), or None for a simulated robot.
        link_file: the link's configuration file, or None.
    """

    description: RobotDescription
    link: LinkConfig | None = None
    link_file: Path | None = None

    @classmethod
    def parse(cls, text: str) -> RobotSpec:
        """The robot `--robot` names (a shipped name, a description file, or zenoh:CONFIG).

        Raises:
            InputError: an unknown name, a missing or malformed file, a link or joint its
                URDF does not have (one line).
            ConfigError: a link configuration's field out of its domain.
        """
        link_file = link_config_path(text)
        if link_file is None:
            return cls(load_description(text))
        link, description = read_link_config(link_file).for_robot()
        return cls(description, link, link_file)

    @property
    def linked(self) -> bool:
        """The robot is at the far end of a link."""
        return self.link is not None

    def __str__(self) -> str:
        return f"zenoh:{self.link_file}" if self.link_file is not None else self.description.name


def _iiwa() -> RobotSpec:
    return RobotSpec.parse("iiwa")


@dataclass(frozen=True)
class LoopOptions:
    """The loop options of `run` and `serve`, checked (module docstring).

    Attributes:
        source: the hand source.
        loop: the loop configuration (mode, rate, lost policy, arbitration, ...).
        utensil: the utensil the person picks (the demo person's; told to the robot unless
            `goal` is "infer"); "" before `resolve_goal`: spoon, or the told goal.
        goal: what the robot is told: "infer" (nothing: it keeps a belief over the utensils,
            `loop.inference`) or the utensil; "" before `resolve_goal`: the utensil.
        change_mind: the demo person turns to this utensil this many seconds into each
            trial (`DemoConfig.change_to`, `change_at_s`), or None.
        robot: the robot (`--robot`), read.
        seed: seed of the goal noise and the demo operator.
        goal_noise_m: goal position noise [m] (None: the task's default).
        record: the session folder (run) or root (serve), or None.
        outputs: what is written beside the sessions: each registered output asked for
            (`app.outputs`, by name) with its checked setting, e.g. {"rerun": RerunTarget}.
        loop_video: play a video source again when it ends.
        rotate: turn video or camera frames [deg clockwise] (None: a video's own rotation).
        allow_partial: accept a video that ends before the frames it declares.
        time_limit_s: a trial without an outcome after this long fails [s] (None: the
            task's default, 120 s).
        history: the operator history file (`--history`), or None: an empty history, kept
            nowhere.
        input_delay_given: the input delay was chosen (`--input-delay`, or a `--config`
            file's loop section), 0 included; otherwise the demo takes its world's delay.
    """

    source: SourceSpec
    loop: LoopConfig
    utensil: str = ""
    goal: str = ""
    change_mind: tuple[str, float] | None = None
    robot: RobotSpec = field(default_factory=_iiwa)
    seed: int = 0
    goal_noise_m: float | None = None
    record: Path | None = None
    outputs: Mapping[str, Any] = field(default_factory=dict)
    loop_video: bool = False
    rotate: int | None = None
    allow_partial: bool = False
    time_limit_s: float | None = None
    history: Path | None = None
    input_delay_given: bool = False

    def __post_init__(self) -> None:
        goal, utensil = resolve_goal(self.goal or None, self.utensil or None)
        object.__setattr__(self, "goal", goal)
        object.__setattr__(self, "utensil", utensil)
        if self.change_mind is not None:
            check_change_mind(self.change_mind, self.source.kind, goal, utensil)

    @property
    def infer(self) -> bool:
        """The robot is not told its utensil."""
        return self.goal == INFER

    @classmethod
    def of(
        cls,
        source: str = "demo",
        loop: LoopConfig | None = None,
        robot: str | RobotSpec = "iiwa",
        **kw: Any,
    ) -> LoopOptions:
        """Options for code (benches, tests): a source in the `--source` grammar, a robot as
        `--robot` names it (or read), the outputs by name with their settings."""
        if isinstance(robot, str):
            robot = RobotSpec.parse(robot)
        return cls(sources.parse(source), loop or LoopConfig(), robot=robot, **kw)


def resolve_goal(goal: str | None, utensil: str | None) -> tuple[str, str]:
    """(`--goal`, `--utensil`) as (what the robot is told: "infer" or a utensil, the person's
    utensil): without `--goal` the robot is told the person's utensil (default spoon); a
    told goal is the person's utensil too.

    Raises:
        ConfigError: an unknown utensil or candidate, or a told goal that is not the
            person's utensil (one line).
    """
    from dsteleop.robot.world import UTENSIL_NAMES  # PyBullet's world: not for --help

    if utensil is not None and utensil not in UTENSIL_NAMES:
        raise ConfigError(
            f"--utensil: unknown utensil {utensil!r} (choose from {', '.join(UTENSIL_NAMES)})"
        )
    if goal is None:
        return utensil or "spoon", utensil or "spoon"
    if goal != INFER and goal not in UTENSIL_NAMES:
        raise ConfigError(
            f"--goal: unknown candidate {goal!r} (choose from {INFER}, {', '.join(UTENSIL_NAMES)})"
        )
    if goal != INFER and utensil is not None and utensil != goal:
        raise ConfigError(
            f"--utensil {utensil} with --goal {goal}: a robot told its goal seeks the person's "
            f"utensil; leave --utensil out, or --goal {INFER} (the robot infers it)"
        )
    return goal, utensil or (goal if goal != INFER else "spoon")


def check_change_mind(change: tuple[str, float], source: str, goal: str, utensil: str) -> None:
    """A change of mind the demo person can make: the demo, a robot that infers its goal, a
    known other utensil, a time > 0.

    Raises:
        ConfigError: one line saying which and why.
    """
    from dsteleop.robot.world import UTENSIL_NAMES

    name, at = change
    if source != "demo":
        raise ConfigError("--change-mind: only the demo person changes its mind (--source demo)")
    if goal != INFER:
        raise ConfigError(
            f"--change-mind with a robot told the {goal}: it would work against the person; "
            f"use --goal {INFER}"
        )
    if name not in UTENSIL_NAMES:
        raise ConfigError(
            f"--change-mind: unknown utensil {name!r} (choose from {', '.join(UTENSIL_NAMES)})"
        )
    if name == utensil:
        raise ConfigError(f"--change-mind {name}: the person wants the {utensil} already")
    if not at > 0:
        raise ConfigError(f"--change-mind: the time must be > 0 seconds, got {at:g}")
