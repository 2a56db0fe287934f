"""The link's configuration file (JSON; docs/link.md has a complete example).

One file serves both ends: the near end (dsteleop, `--robot zenoh:CONFIG`) and the far end
(the robot's driver, `dsteleop robot-sim --zenoh CONFIG`). Every field has a default, so
`{}` is a valid file: the far end (the robot) listens on tcp/127.0.0.1:7447 and the near end
connects there (as ROS 2 nodes on rmw_zenoh connect to their router; the near end retries
after the far end went away), ROS_DOMAIN_ID 0, the topics under /dsteleop/, the KUKA iiwa
(its description's fingers, and limits from its description: `link_limits`).

    {
      "domain_id": 0,
      "near": {"listen": [], "connect": ["tcp/127.0.0.1:7447"]},
      "far":  {"listen": ["tcp/127.0.0.1:7447"], "connect": []},
      "topics": {"command_pose": "/dsteleop/palm_pose_command", ...},
      "robot": "iiwa",
      "base_frame": "base",
      "finger_names": ["thumb", "index", "middle", "ring"],
      "command_timeout_s": 0.2, "connect_timeout_s": 2.0,
      "rate_hz": 30.0,
      "limits": {"workspace_min_m": [...], "workspace_max_m": [...], "max_speed_m_s": 0.5,
                 "max_rate_rad_s": 2.0, "max_finger_rate_per_s": 8.0}
    }
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dsteleop.app.ports import RobotLimits
from dsteleop.errors import ConfigError, InputError
from dsteleop.robot.description import RobotDescription, description_path, load_description

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: A Zenoh locator: protocol/address:port (tcp, udp, tls, quic, ws; IPv6 in brackets).
_LOCATOR = re.compile(r"^(tcp|udp|tls|quic|ws)/(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}$")
#: A ROS 2 topic name: tokens of letters, digits and underscores separated by "/".
_TOPIC = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


#: The link's speed limits are the description's times this: the loop already commands
#: within the description's limits (the arbitration's), so the link only cuts what no mode
#: commands (a jump after a reset, a bad command), not a tick that came early.
LINK_SPEED_FACTOR = 2.0


def link_limits(desc: RobotDescription) -> RobotLimits:
    """The link's default limits for a robot: its description's workspace box, and its
    speed limits times `LINK_SPEED_FACTOR`."""
    k = LINK_SPEED_FACTOR
    return RobotLimits(
        desc.workspace_min_m,
        desc.workspace_max_m,
        k * desc.max_speed_m_s,
        k * desc.max_rate_rad_s,
        k * desc.max_finger_rate_per_s,
    )


@dataclass(frozen=True)
class Endpoints:
    """Where one end's Zenoh session listens and what it connects to (Zenoh locators)."""

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for e in (*self.listen, *self.connect):
            if not isinstance(e, str) or not _LOCATOR.match(e):
                raise ConfigError(
                    f"link config: {e!r} is not a Zenoh endpoint like {DEFAULT_ENDPOINT}"
                )
        if not self.listen and not self.connect:
            raise ConfigError("link config: an end needs a listen or a connect endpoint")


@dataclass(frozen=True)
class Topics:
    """ROS 2 topic names of the link (fully qualified; the leading "/" is optional).

    Attributes:
        command_pose: near -> far, geometry_msgs/PoseStamped: the commanded palm pose.
        command_fingers: near -> far, sensor_msgs/JointState: finger openness targets in
            [0, 1], one per finger name (a gripper: one).
        state_pose: far -> near, PoseStamped: the measured palm pose.
        state_joints: far -> near, JointState: the measured joint positions [rad or m].
        state_fingers: far -> near, JointState: the finger openness the robot is holding.
    """

    command_pose: str = "/dsteleop/palm_pose_command"
    command_fingers: str = "/dsteleop/finger_command"
    state_pose: str = "/dsteleop/palm_pose"
    state_joints: str = "/dsteleop/joint_states"
    state_fingers: str = "/dsteleop/finger_state"

    def __post_init__(self) -> None:
        names = dataclasses.astuple(self)
        for f, v in zip(dataclasses.fields(self), names, strict=True):
            if not isinstance(v, str) or not _TOPIC.match(v):
                raise ConfigError(f"link config: topics.{f.name} {v!r} is not a ROS 2 topic name")
        if len({n.strip("/") for n in names}) != len(names):
            raise ConfigError("link config: two topics have the same name")


@dataclass(frozen=True)
class LinkConfig:
    """The link's settings (module docstring), validated at construction.

    Attributes:
        domain_id: ROS_DOMAIN_ID, the first chunk of every key expression.
        near: the near end's (dsteleop's) endpoints.
        far: the far end's (the robot driver's) endpoints.
        topics: topic names.
        robot: the arm's description (`--robot NAME|FILE`, docs/robots.md; a relative FILE
            is read from the configuration file's folder): both ends build from it (the
            far end's simulated arm, the near end's limits, fingers, joint order and twin).
        base_frame: frame_id of every pose (the robot's base frame).
        finger_names: the robot's fingers on the wire, in the order of the openness vector
            (empty: the description's; given: they must be the description's).
        command_timeout_s: the far end drops a command older than this and halts the robot
            when no fresh command came for this long [s].
        connect_timeout_s: opening a session fails when no connect endpoint answers within
            this [s].
        rate_hz: the far end's control and publishing rate [Hz].
        limits: the robot's workspace and speed limits; the near end never sends outside them
            (None: `link_limits` of the description).
    """

    domain_id: int = 0
    near: Endpoints = field(default_factory=lambda: Endpoints(connect=(DEFAULT_ENDPOINT,)))
    far: Endpoints = field(default_factory=lambda: Endpoints(listen=(DEFAULT_ENDPOINT,)))
    topics: Topics = field(default_factory=Topics)
    robot: str = "iiwa"
    base_frame: str = "base"
    finger_names: tuple[str, ...] = ()
    command_timeout_s: float = 0.2
    connect_timeout_s: float = 2.0
    rate_hz: float = 30.0
    limits: RobotLimits | None = None

    def __post_init__(self) -> None:
        if isinstance(self.domain_id, bool) or not isinstance(self.domain_id, int):
            raise ConfigError(f"link config: domain_id must be an integer, got {self.domain_id!r}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"link config: domain_id must be in 0..232, got {self.domain_id}")
        for name in ("command_timeout_s", "connect_timeout_s", "rate_hz"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"link config: {name} must be a number, got {v!r}")
            if v <= 0:
                raise ConfigError(f"link config: {name} must be > 0, got {v}")
        if not all(isinstance(f, str) and f for f in self.finger_names):
            raise ConfigError("link config: finger_names must be a list of names")
        if not isinstance(self.robot, str) or not self.robot:
            raise ConfigError("link config: robot must be a robot description's name or file")
        if not isinstance(self.base_frame, str) or not self.base_frame:
            raise ConfigError("link config: base_frame must be a non-empty string")

    def for_robot(self) -> tuple[LinkConfig, RobotDescription]:
        """This configuration with the description's fingers and limits filled in, and the
        description.

        Raises:
            InputError: the description does not load (one line).
            ConfigError: `finger_names` are not the description's.
        """
        desc = load_description(self.robot)
        names = self.finger_names or desc.finger_names
        if names != desc.finger_names:
            raise ConfigError(
                f"link config: finger_names {list(names)} are not robot {desc.name}'s "
                f"{list(desc.finger_names)}"
            )
        limits = self.limits or link_limits(desc)
        return dataclasses.replace(self, finger_names=names, limits=limits), desc

    def to_json(self) -> dict[str, Any]:
        """The file's object (what `read_link_config` reads back to the same config)."""
        return dataclasses.asdict(self)


def _section(cls: type, data: Any, name: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"link config: {name} must be a JSON object")
    known = {f.name for f in dataclasses.fields(cls)}
    extra = sorted(set(data) - known)
    if extra:
        raise ConfigError(f"link config: unknown field {name}.{extra[0]}")
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    try:
        return cls(**kw)
    except TypeError as exc:
        raise ConfigError(f"link config: {name}: {exc}") from None


def link_config_from_json(data: Any) -> LinkConfig:
    """A `LinkConfig` from the file's object; unknown or ill-typed fields are a ConfigError."""
    if not isinstance(data, dict):
        raise ConfigError("link config: expected a JSON object")
    kw: dict[str, Any] = {}
    for k, v in data.items():
        if k in ("near", "far"):
            kw[k] = _section(Endpoints, v, k)
        elif k == "topics":
            kw[k] = _section(Topics, v, k)
        elif k == "limits":
            kw[k] = None if v is None else _section(RobotLimits, v, k)
        elif k == "finger_names":
            if not isinstance(v, list):
                raise ConfigError("link config: finger_names must be a list")
            kw[k] = tuple(v)
        else:
            kw[k] = v
    return _section(LinkConfig, kw, "link")


def read_link_config(path: Path | str) -> LinkConfig:
    """Read a link configuration file (module docstring).

    Raises:
        InputError: the file is missing or not JSON, or its `robot` names no robot
            description (the message names the file and the field, not `--robot`).
        ConfigError: a field is unknown or out of its domain.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise InputError(f"link config: file not found: {p}") from None
    except OSError as exc:
        raise InputError(f"link config: cannot read {p} ({exc.strerror})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"link config {p}: not a JSON file ({exc})") from None
    config = link_config_from_json(data)
    robot = Path(config.robot)
    if robot.suffix == ".toml" and not robot.is_absolute():
        config = dataclasses.replace(config, robot=str(p.parent / robot))
    # The robot is the file's (its field `robot`), not the command line's: say so.
    description_path(config.robot, given_by=f"link config {p}: field robot")
    return config


def link_config_path(robot: str) -> Path | None:
    """The configuration file `--robot zenoh:CONFIG` names, or None for another robot.

    Raises:
        ConfigError: `zenoh:` without a file.
    """
    kind, sep, rest = robot.partition(":")
    if not sep or kind != "zenoh":
        return None
    if not rest:
        raise ConfigError("--robot zenoh:CONFIG: the link's configuration file is missing")
    return Path(rest)
