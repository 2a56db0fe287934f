"""A robot is a description, not code: one small TOML file per robot (docs/robots.md).

A description names the robot's URDF (from the installed `pybullet_data` or
`example-robot-data`, `DATA_PACKAGES`, or a file beside the description), an optional hand
mounted on the arm (a second URDF and the fixed joint that joins them), the arm's joints and
rest posture, the palm link and the palm frame in it, the fingers (each finger: its joints,
each joint's open and closed position, the motor effort, and the human fingers whose
openness it follows), the home pose and the velocity and workspace limits, and optionally
where the task's scene stands in its base frame (`[task]`, `robot.placement`; else computed,
`robot.reach`) and whether its arm holds its own weight (`[arm] gravity_compensation`, default
true). `robot/robots/` ships `iiwa.toml` (the KUKA iiwa with the project's four-finger hand),
`panda.toml` (the Franka Panda of `pybullet_data` with its two-finger gripper: one finger,
`gripper`, whose openness drives both jaws), `ur5.toml` (the UR5 with the project's hand),
`xarm6.toml` (the xArm 6 with its linkage gripper: one drive joint and its mimics) and
`so101.toml` (LeRobot's SO-101, which cannot reach the kitchen task).

`load_description(NAME_OR_FILE)` reads and validates one: a shipped name, or a path to a
`.toml` file. Everything wrong with it (a malformed file, a missing field, a number outside
its range in `RANGES`, a joint or link the URDF does not have, a finger position outside its
joint's URDF limits, a mesh found nowhere) is one `InputError` naming the file and the
field. The URDFs are read by the one URDF reader (`robot.urdf`: top-level joints only,
`<mimic>` couplings, meshes along `package_path` and `ROS_PACKAGE_PATH`). Nothing is read
from the network: URDFs come from installed packages, the repository or the user's files.

The palm frame (docs/robot.md): origin where the fingers start (the palm's inner face),
+z the approach direction (the way open fingers point), the fingers close along y. The task
(`robot.task`) and the demo operator are written in this frame, so a new robot fits the
kitchen task when its palm frame follows it.

Why one module: it is the one definition of the description format. Its dataclasses, the
range of every field (`RANGES`), the parser that reads the TOML into them and the check of
every name and limit against the URDF walk the same fields in the same order; split, a new
field would be added in three files and could be parsed but not checked. The reader of the
URDF itself (`robot.urdf`), where the scene stands (`robot.placement`, `robot.reach`) and
what a description's robot can do (`robot.check`) are modules of their own.
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.errors import InputError
from dsteleop.robot.placement import Placement
from dsteleop.robot.urdf import UrdfModel, no_joint, package_search_path, resolve_meshes

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: Where the shipped descriptions live; `--robot NAME` looks here.
ROBOTS_DIR = Path(__file__).resolve().parent / "robots"
#: The robot of sessions recorded before robots were descriptions.
DEFAULT_ROBOT = "iiwa"
#: The human fingers a robot finger may follow (tracking.landmarks.FINGER_NAMES).
HUMAN_FINGERS = ("thumb", "index", "middle", "ring", "little")
PYBULLET_DATA = "pybullet_data:"
#: Installed data packages a URDF reference may name as `PACKAGE:PATH` (PATH inside the
#: package's data folder), besides `pybullet_data:`: the distribution that ships it and its
#: data folder inside the installed distribution (cmeel's layout: `cmeel.prefix/share/NAME`).
#: The `robots` extra installs them (pyproject.toml); nothing is downloaded at run time.
DATA_PACKAGES: dict[str, str] = {
    "example-robot-data": "cmeel.prefix/share/example-robot-data",
}
#: Where the task's grasp goal puts a grasp frame by default: 12 mm above the grip's top end
#: (`grip.depth_m`, negative: above), with the grasp frame at the palm origin: the iiwa's
#: four-finger hand, whose fingers wrap the grip from above.
DEFAULT_GRASP_DEPTH_M = -0.012
#: The finger links' torsional (spinning) friction by default (`grip.spinning_friction`).
DEFAULT_SPINNING_FRICTION = 0.002
TAU = 2.0 * math.pi


@dataclass(frozen=True)
class Range:
    """The values a description's number may take: lo..hi, each end open or closed."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False

    def __contains__(self, v: float) -> bool:
        above = v > self.lo if self.lo_open else v >= self.lo
        below = v < self.hi if self.hi_open else v <= self.hi
        return above and below

    def __str__(self) -> str:
        def num(v: float) -> str:
            return {TAU: "2pi", -TAU: "-2pi", math.pi: "pi", -math.pi: "-pi"}.get(v, f"{v:g}")

        lo, hi = num(self.lo), num(self.hi)
        return f"{'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"


#: Every number a description holds and the range it must lie in (docs/robots.md gives the
#: reasons); a vector's every component. Keys are field paths without list indices
#: (`fingers.joints.open` for `fingers[0].joints[1].open`). Finger joints' open and closed
#: positions and the rest posture must also lie within their joints' URDF limits.
RANGES: dict[str, Range] = {
    "arm.rest_posture_rad": Range(-TAU, TAU),
    # PyBullet's position motor closes this share of the joint error per physics step:
    # above 1 it overshoots and the arm diverges (at 2.0 the palm ended 0.42 m below the table)
    "arm.position_gain": Range(0.0, 1.0, lo_open=True),
    "mount.xyz_m": Range(-1.0, 1.0),
    "mount.rpy_rad": Range(-TAU, TAU),
    "palm.xyz_m": Range(-1.0, 1.0),
    "palm.rpy_rad": Range(-TAU, TAU),
    "fingers.force": Range(0.0, 5000.0, lo_open=True),
    "fingers.squeeze_share": Range(0.0, 1.0, lo_open=True),
    "fingers.joints.open": Range(-TAU, TAU),
    "fingers.joints.closed": Range(-TAU, TAU),
    "grip.tcp_xyz_m": Range(-0.5, 0.5),
    "grip.depth_m": Range(-0.1, 0.08),  # from 10 cm above the grip to its bottom (8 cm)
    "grip.spinning_friction": Range(0.0, 1.0),
    "home.position_m": Range(-3.0, 3.0),
    "home.rotvec_rad": Range(-TAU, TAU),
    "limits.workspace_min_m": Range(-3.0, 3.0),
    "limits.workspace_max_m": Range(-3.0, 3.0),
    "limits.shoulder_m": Range(-3.0, 3.0),
    "limits.reach_m": Range(0.0, 3.0, lo_open=True),
    "limits.max_speed_m_s": Range(0.0, 2.0, lo_open=True),
    "limits.max_rate_rad_s": Range(0.0, TAU, lo_open=True),
    "limits.max_finger_rate_per_s": Range(0.0, 30.0, lo_open=True),
    # the task's scene in the base frame (`robot.placement`): within a metre, half a turn
    "task.xyz_m": Range(-1.0, 1.0),
    "task.yaw_rad": Range(-math.pi, math.pi),
}


@dataclass(frozen=True)
class FingerJoint:
    """One joint of a finger.

    Attributes:
        name: URDF joint name (revolute [rad] or prismatic [m]).
        open: its position when the finger is open (openness 1) [rad or m].
        closed: its position when the finger is closed (openness 0) [rad or m].
        group: its link's contact group: a body is clamped when the links of the
            description's `opposing` group and of another group touch it.
    """

    name: str
    open: float
    closed: float
    group: str


@dataclass(frozen=True)
class Finger:
    """One openness dimension of the robot.

    Attributes:
        name: the dimension's name ("thumb", "gripper", ...).
        joints: its joints; openness g sets each to closed + g (open - closed).
        force: motor effort limit of each of its joints [N m, or N for prismatic joints].
        human: the human fingers whose mean openness it follows (the mapping).
        squeeze_share: once it holds a body, each joint closes at most this share of its
            open-to-closed travel past where it met it (the contact stall, `robot.arm`);
            None: the robot config's (`RobotConfig.squeeze_share`).
    """

    name: str
    joints: tuple[FingerJoint, ...]
    force: float
    human: tuple[str, ...]
    squeeze_share: float | None = None


@dataclass(frozen=True)
class MimicJoint:
    """A URDF joint coupled to a finger joint by `<mimic>` (`robot.urdf`): the robot drives
    it at multiplier * q_master + offset, within its own limits (PyBullet ignores the tag).

    Attributes:
        name: the mimic joint's URDF name.
        master: the finger joint it follows (through a chain of mimics, composed).
        multiplier: m of q = m q_master + o.
        offset: o [rad or m].
        lower: its URDF lower limit [rad or m] (None: unlimited).
        upper: its URDF upper limit (None: unlimited).
    """

    name: str
    master: str
    multiplier: float
    offset: float
    lower: float | None
    upper: float | None


@dataclass(frozen=True)
class Mount:
    """A hand mounted on the arm: its URDF joined to the arm by a fixed joint.

    Attributes:
        urdf: the hand's URDF (module docstring: where URDFs come from).
        joint: name of the fixed joint that joins them.
        parent_link: the arm's link the hand is mounted on.
        child_link: the hand's root link.
        xyz_m: the hand root's position in the parent link frame [m].
        rpy_rad: its orientation (roll, pitch, yaw) [rad].
    """

    urdf: str
    joint: str
    parent_link: str
    child_link: str
    xyz_m: tuple[float, float, float]
    rpy_rad: tuple[float, float, float]


@dataclass(frozen=True)
class RobotDescription:
    """A robot (module docstring); build with `load_description`.

    Attributes:
        name: short name (`--robot NAME`).
        title: one line for people.
        path: the description file.
        urdf: the arm's URDF.
        mount: a hand mounted on the arm, or None (the URDF has its own).
        arm_joints: the arm's revolute joints from base to wrist.
        rest_posture_rad: the arm's null-space rest posture, per arm joint [rad].
        arm_position_gain: PyBullet position gain of the arm's motors (how stiffly they
            hold a command against gravity: the Panda's lighter joints need 1.0, the iiwa
            0.3).
        palm_link: the link the palm frame is fixed to.
        palm_xyz_m: the palm frame's origin in that link's frame [m].
        palm_rpy_rad: its orientation [rad].
        fingers: the openness dimensions, in order.
        opposing: the contact group that opposes the others (a clamp needs it and another).
        grasp_xyz_m: the grasp frame (the tool centre point: where the fingers close, e.g.
            between a gripper's pads) in the palm frame [m]; same orientation as the palm.
        grasp_depth_m: how far below the grip's top end the task's grasp goal puts the
            grasp frame, along the handle [m] (negative: above it).
        spinning_friction: the finger links' torsional friction (PyBullet's
            `spinningFriction`, resisting a held body's turning about the contact normal).
        home_position_m: palm position at a reset, base frame [m].
        home_rotvec_rad: palm orientation at a reset, rotation vector [rad].
        workspace_min_m: lower corner of the box palm targets are clamped into [m].
        workspace_max_m: upper corner [m].
        shoulder_m: centre of the reach sphere [m].
        reach_m: radius of the reach sphere for the palm origin [m].
        max_speed_m_s: palm linear speed limit [m/s].
        max_rate_rad_s: palm angular speed limit [rad/s].
        max_finger_rate_per_s: openness rate limit [1/s].
        text: the description file's text (recorded with a session).
        prismatic_joints: the finger joints that are prismatic in the URDF (positions in m;
            every other joint is revolute, in rad), filled in from the URDF at loading.
        package_path: folders (relative to the description file) that `package://` and
            relative mesh paths are looked up in, before `ROS_PACKAGE_PATH` (`robot.urdf`).
        link_groups: (link, contact group) pairs: links (a mimic joint's, a linkage's pad)
            whose contact group is not their finger joint's (`grip.link_groups`).
        mimic_joints: the URDF's joints coupled to a finger joint by `<mimic>`, filled in
            from the URDF at loading; each takes its finger joint's contact group unless
            `link_groups` names its link.
        finger_limits: (joint, lower, upper) of every finger joint with URDF limits, filled
            in at loading.
        task_xyz_m: `[task] xyz_m`: the task's scene origin in the base frame [m]
            (`robot.placement`), or None: no `[task]` table (the placement is computed).
        task_yaw_rad: `[task] yaw_rad`: the scene's turn about the base z axis [rad].
        gravity_compensation: `[arm] gravity_compensation`: the arm holds its own weight
            (`robot.arm`, steady state; default true).
    """

    name: str
    title: str
    path: Path
    urdf: str
    mount: Mount | None
    arm_joints: tuple[str, ...]
    rest_posture_rad: tuple[float, ...]
    arm_position_gain: float
    palm_link: str
    palm_xyz_m: tuple[float, float, float]
    palm_rpy_rad: tuple[float, float, float]
    fingers: tuple[Finger, ...]
    opposing: str
    home_position_m: tuple[float, float, float]
    home_rotvec_rad: tuple[float, float, float]
    workspace_min_m: tuple[float, float, float]
    workspace_max_m: tuple[float, float, float]
    shoulder_m: tuple[float, float, float]
    reach_m: float
    max_speed_m_s: float
    max_rate_rad_s: float
    max_finger_rate_per_s: float
    grasp_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    grasp_depth_m: float = DEFAULT_GRASP_DEPTH_M
    spinning_friction: float = DEFAULT_SPINNING_FRICTION
    text: str = ""
    prismatic_joints: frozenset[str] = frozenset()
    package_path: tuple[str, ...] = ()
    link_groups: tuple[tuple[str, str], ...] = ()
    mimic_joints: tuple[MimicJoint, ...] = ()
    finger_limits: tuple[tuple[str, float, float], ...] = ()
    task_xyz_m: tuple[float, float, float] | None = None
    task_yaw_rad: float = 0.0
    gravity_compensation: bool = True

    @property
    def task_placement(self) -> Placement | None:
        """Where the description stands the task's scene (its `[task]` table,
        `robot.placement`), or None: it says nothing (`robot.reach.task_placement` decides)."""
        if self.task_xyz_m is None:
            return None
        return Placement(self.task_xyz_m, self.task_yaw_rad, "description")

    @property
    def finger_names(self) -> tuple[str, ...]:
        """The openness dimensions' names, in order."""
        return tuple(f.name for f in self.fingers)

    @property
    def finger_joints(self) -> tuple[FingerJoint, ...]:
        """Every finger joint, finger by finger."""
        return tuple(j for f in self.fingers for j in f.joints)

    @property
    def palm_frame_link(self) -> str:
        """The link whose frame is the palm frame: `palm_link` itself when the offset is
        zero, else a massless link `dsteleop_palm` fixed to it (`robot.model`)."""
        if any(self.palm_xyz_m) or any(self.palm_rpy_rad):
            return "dsteleop_palm"
        return self.palm_link

    def resolve(self, ref: str) -> Path:
        """The file a URDF reference names (`pybullet_data:PATH`, `example-robot-data:PATH`
        (`DATA_PACKAGES`), or a path relative to the description file).

        Raises:
            InputError: the reference names a data package that is not installed (one line
                naming the `pip install` that brings it).
        """
        if ref.startswith(PYBULLET_DATA):
            import pybullet_data

            return Path(pybullet_data.getDataPath()) / ref[len(PYBULLET_DATA) :]
        package, sep, rest = ref.partition(":")
        if sep and package in DATA_PACKAGES:
            return data_package_dir(package, f"robot description {self.path}: {ref!r}") / rest
        p = Path(ref)
        return p if p.is_absolute() else (self.path.parent / p).resolve()

    def search_path(self) -> tuple[Path, ...]:
        """Where meshes are looked up (`robot.urdf.package_search_path`): `package_path`,
        then `ROS_PACKAGE_PATH`, then `AMENT_PREFIX_PATH`'s share folders."""
        return package_search_path(self.resolve(d) for d in self.package_path)

    def to_dict(self) -> dict[str, Any]:
        """What a session records: the name and the file (and its text, so a replay
        elsewhere can rebuild it)."""
        return {"name": self.name, "path": str(self.path), "text": self.text}


def data_package_dir(package: str, where: str) -> Path:
    """The installed data folder of `package` (a key of `DATA_PACKAGES`).

    Raises:
        InputError: the package is not installed, or installed without its data folder.
    """
    from importlib import metadata

    try:
        dist = metadata.distribution(package)
    except metadata.PackageNotFoundError:
        raise InputError(
            f"{where}: the package {package} is not installed "
            f"(pip install 'dsteleop[robots]', or pip install {package})"
        ) from None
    d = Path(str(dist.locate_file(DATA_PACKAGES[package])))
    if not d.is_dir():
        raise InputError(
            f"{where}: the installed {package} {dist.version} has no {DATA_PACKAGES[package]} "
            f"(reinstall it: pip install --force-reinstall {package})"
        )
    return d


def shipped_robots() -> tuple[str, ...]:
    """Names of the descriptions in `ROBOTS_DIR`."""
    return tuple(sorted(p.stem for p in ROBOTS_DIR.glob("*.toml")))


def description_path(name_or_file: str, given_by: str = "--robot") -> Path:
    """The file `--robot NAME|FILE` names (`given_by`: where the name came from, for the
    one-line errors, e.g. a link configuration file's `robot` field).

    Raises:
        InputError: no shipped robot of that name and no such file.
    """
    p = Path(name_or_file)
    if p.suffix == ".toml" or p.is_file():
        if not p.is_file():
            raise InputError(f"{given_by}: no such robot description file: {name_or_file}")
        return p.resolve()
    shipped = ROBOTS_DIR / f"{name_or_file}.toml"
    if shipped.is_file():
        return shipped
    raise InputError(
        f"{given_by}: unknown robot {name_or_file!r} (shipped: {', '.join(shipped_robots())}; "
        "or a .toml file)"
    )


def load_description(name_or_file: str, given_by: str = "--robot") -> RobotDescription:
    """Read and validate a robot description (module docstring); `given_by` names where
    the name came from in the one-line errors.

    Raises:
        InputError: the file is missing or malformed, or a field is wrong (one line).
    """
    path = description_path(name_or_file, given_by)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"robot description {path}: cannot be read ({exc})") from None
    return _from_text(text, path)


def _from_text(text: str, path: Path) -> RobotDescription:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"robot description {path}: not valid TOML ({exc})") from None
    desc = dataclasses.replace(_parse(data, path), text=text)
    return check_against_urdf(desc)


def description_from_record(meta: dict[str, Any] | None) -> RobotDescription:
    """The robot a session recorded (`meta["description"]`: its name, file and text), or
    the iiwa for a session recorded before robots were descriptions. The recorded text is
    what counts (the file may have changed or gone since); its URDFs are looked up as the
    recorded file would have (installed packages, or beside it).

    Raises:
        InputError: the recorded description no longer loads (a URDF beside it is gone).
    """
    rec = (meta or {}).get("description")
    if not isinstance(rec, dict) or not isinstance(rec.get("text"), str):
        return load_description(DEFAULT_ROBOT)
    return _from_text(rec["text"], Path(str(rec.get("path", "recorded.toml"))))


class _Fields:
    """Typed access to one TOML table, with errors naming the file and the field."""

    def __init__(self, data: Any, path: Path, where: str = "") -> None:
        if not isinstance(data, dict):
            raise InputError(f"robot description {path}: {where or 'the file'} must be a table")
        self.d, self.path, self.where = data, path, where

    def _name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def fail(self, key: str, what: str) -> InputError:
        return InputError(f"robot description {self.path}: {self._name(key)} {what}")

    def has(self, key: str) -> bool:
        return key in self.d

    def get(self, key: str) -> Any:
        if key not in self.d:
            raise self.fail(key, "is missing")
        return self.d[key]

    def text(self, key: str) -> str:
        v = self.get(key)
        if not isinstance(v, str) or not v:
            raise self.fail(key, f"must be a non-empty string, got {v!r}")
        return v

    def _in_range(self, key: str, v: float, shown: Any) -> None:
        r = RANGES.get(re.sub(r"\[\d+\]", "", self._name(key)))
        if r is not None and v not in r:
            raise self.fail(key, f"must be in {r}, got {shown!r}")

    def num(self, key: str) -> float:
        v = self.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(key, f"must be a finite number, got {v!r}")
        self._in_range(key, float(v), v)
        return float(v)

    def vec3(self, key: str, default: tuple[float, float, float] | None = None) -> Any:
        if default is not None and key not in self.d:
            return default
        return self.nums(key, 3)

    def strs(self, key: str) -> tuple[str, ...]:
        v = self.get(key)
        if not isinstance(v, list) or not v or not all(isinstance(x, str) and x for x in v):
            raise self.fail(key, f"must be a non-empty list of names, got {v!r}")
        return tuple(v)

    def nums(self, key: str, n: int) -> tuple[float, ...]:
        v = self.get(key)
        ok = isinstance(v, list) and len(v) == n
        ok = ok and all(not isinstance(x, bool) and isinstance(x, (int, float)) for x in v)
        if not ok or not all(math.isfinite(x) for x in v):
            raise self.fail(key, f"must be {n} finite numbers, got {v!r}")
        for x in v:
            self._in_range(key, float(x), v)
        return tuple(float(x) for x in v)

    def text_map(self, key: str) -> tuple[tuple[str, str], ...]:
        """A table of names to names (`grip.link_groups`), as sorted pairs; () if absent."""
        if key not in self.d:
            return ()
        v = self.d[key]
        if not isinstance(v, dict) or not all(
            isinstance(k, str) and k and isinstance(x, str) and x for k, x in v.items()
        ):
            raise self.fail(key, f"must be a table of names to names, got {v!r}")
        return tuple(sorted(v.items()))

    def table(self, key: str) -> _Fields:
        return _Fields(self.get(key), self.path, self._name(key))

    def tables(self, key: str) -> list[_Fields]:
        v = self.get(key)
        if not isinstance(v, list) or not v:
            raise self.fail(key, "must be a non-empty list of tables")
        return [_Fields(x, self.path, f"{self._name(key)}[{i}]") for i, x in enumerate(v)]


def _package_path(f: _Fields) -> tuple[str, ...]:
    return f.strs("package_path") if f.has("package_path") else ()


def _parse(data: Any, path: Path) -> RobotDescription:
    f = _Fields(data, path)
    arm = f.table("arm")
    arm_joints = arm.strs("joints")
    mount = None
    if f.has("mount"):
        m = f.table("mount")
        mount = Mount(
            m.text("urdf"),
            m.text("joint"),
            m.text("parent_link"),
            m.text("child_link"),
            m.vec3("xyz_m", (0.0, 0.0, 0.0)),
            m.vec3("rpy_rad", (0.0, 0.0, 0.0)),
        )
    palm = f.table("palm")
    fingers = []
    for t in f.tables("fingers"):
        name = t.text("name")
        joints = []
        for jt in t.tables("joints"):
            o, c = jt.num("open"), jt.num("closed")
            if o == c:
                raise jt.fail("closed", "must differ from open")
            group = jt.text("group") if jt.has("group") else name
            joints.append(FingerJoint(jt.text("name"), o, c, group))
        human = t.strs("human")
        bad = [h for h in human if h not in HUMAN_FINGERS]
        if bad:
            raise t.fail("human", f"names no human finger: {bad} (of {', '.join(HUMAN_FINGERS)})")
        squeeze = t.num("squeeze_share") if t.has("squeeze_share") else None
        force = t.num("force")
        fingers.append(Finger(name, tuple(joints), force, human, squeeze))
    names = [x.name for x in fingers]
    if len(set(names)) != len(names):
        raise f.fail("fingers", f"has a name twice: {names}")
    grip = f.table("grip")
    opposing = grip.text("opposing")
    grasp_depth_m = grip.num("depth_m") if grip.has("depth_m") else DEFAULT_GRASP_DEPTH_M
    spinning = DEFAULT_SPINNING_FRICTION
    if grip.has("spinning_friction"):
        spinning = grip.num("spinning_friction")
    link_groups = grip.text_map("link_groups")
    groups = {j.group for x in fingers for j in x.joints} | {g for _, g in link_groups}
    if opposing not in groups or len(groups) < 2:
        raise grip.fail(
            "opposing", f"must be one of two or more finger contact groups {sorted(groups)}"
        )
    home = f.table("home")
    lim = f.table("limits")
    lo, hi = lim.vec3("workspace_min_m"), lim.vec3("workspace_max_m")
    if not all(a < b for a, b in zip(lo, hi, strict=True)):
        raise lim.fail("workspace_min_m", "must be below workspace_max_m on every axis")
    desc = RobotDescription(
        name=f.text("name"),
        title=f.text("title") if f.has("title") else f.text("name"),
        path=path,
        urdf=arm.text("urdf"),
        mount=mount,
        arm_joints=arm_joints,
        rest_posture_rad=arm.nums("rest_posture_rad", len(arm_joints)),
        arm_position_gain=arm.num("position_gain"),
        palm_link=palm.text("link"),
        palm_xyz_m=palm.vec3("xyz_m", (0.0, 0.0, 0.0)),
        palm_rpy_rad=palm.vec3("rpy_rad", (0.0, 0.0, 0.0)),
        fingers=tuple(fingers),
        opposing=opposing,
        home_position_m=home.vec3("position_m"),
        home_rotvec_rad=home.vec3("rotvec_rad"),
        workspace_min_m=lo,
        workspace_max_m=hi,
        shoulder_m=lim.vec3("shoulder_m"),
        reach_m=lim.num("reach_m"),
        max_speed_m_s=lim.num("max_speed_m_s"),
        max_rate_rad_s=lim.num("max_rate_rad_s"),
        max_finger_rate_per_s=lim.num("max_finger_rate_per_s"),
        grasp_xyz_m=grip.vec3("tcp_xyz_m", (0.0, 0.0, 0.0)),
        grasp_depth_m=grasp_depth_m,
        spinning_friction=spinning,
        package_path=_package_path(f),
        link_groups=link_groups,
    )
    if arm.has("gravity_compensation"):
        gc = arm.get("gravity_compensation")
        if not isinstance(gc, bool):
            raise arm.fail("gravity_compensation", f"must be true or false, got {gc!r}")
        desc = dataclasses.replace(desc, gravity_compensation=gc)
    if f.has("task"):
        t = f.table("task")
        known = {"xyz_m", "yaw_rad"}
        if set(t.d) - known:
            raise t.fail(sorted(set(t.d) - known)[0], "is not a field of [task] (xyz_m, yaw_rad)")
        desc = dataclasses.replace(
            desc,
            task_xyz_m=t.vec3("xyz_m", (0.0, 0.0, 0.0)),
            task_yaw_rad=t.num("yaw_rad") if t.has("yaw_rad") else 0.0,
        )
    if not all(a <= b <= c for a, b, c in zip(lo, desc.home_position_m, hi, strict=True)):
        raise home.fail("position_m", "must lie inside the workspace box")
    return desc


def urdf_models(desc: RobotDescription, meshes: bool = True) -> list[UrdfModel]:
    """The description's URDFs (the arm's, then a mounted hand's), parsed by the one reader
    (`robot.urdf`), their meshes resolved to absolute files against `desc.search_path()`.

    Raises:
        InputError: a URDF is missing or malformed, or a mesh is found nowhere (one line).
    """
    refs = [("arm.urdf", desc.urdf)]
    if desc.mount is not None:
        refs.append(("mount.urdf", desc.mount.urdf))
    out = []
    search = desc.search_path()
    for field_name, ref in refs:
        p = desc.resolve(ref)
        where = f"robot description {desc.path}: {field_name} {ref!r}"
        model = UrdfModel.read(p, where)
        if meshes:
            resolve_meshes(model, search, f"robot description {desc.path}: {field_name} {p}")
        out.append(model)
    return out


def check_against_urdf(desc: RobotDescription) -> RobotDescription:
    """Every joint and link the description names exists in its URDF(s) (top-level
    elements only, `robot.urdf`), with the right type, every finger position within its
    joint's limits, every mesh found; and what the URDF adds (prismatic finger joints,
    mimic joints, finger limits) filled in.

    Raises:
        InputError: naming the first problem and its field.
    """
    models = urdf_models(desc)
    joints = {n: j for m in models for n, j in m.joints.items()}
    links = frozenset().union(*(m.links for m in models))
    elsewhere = frozenset().union(*(m.named_elsewhere for m in models))
    model = models[0]

    def fail(what: str) -> InputError:
        return InputError(f"robot description {desc.path}: {what}")

    def missing(n: str) -> str:
        return no_joint(n, elsewhere)

    for k, n in enumerate(desc.arm_joints):
        j = joints.get(n)
        if j is None:
            raise fail(f"arm.joints: {missing(n)}")
        if j.type is None:
            raise fail(f"arm.joints: the URDF's joint {n!r} has no type attribute")
        if j.type != "revolute":
            raise fail(f"arm.joints: {n!r} is {j.type}, not revolute")
        lim = j.limits
        q = desc.rest_posture_rad[k]
        if lim is not None and not lim[0] <= q <= lim[1]:
            raise fail(
                f"arm.rest_posture_rad[{k}] {q:g} is outside {n!r}'s URDF limits "
                f"[{lim[0]:g}, {lim[1]:g}]"
            )
    if desc.mount is not None:
        for key, name in (
            ("parent_link", desc.mount.parent_link),
            ("child_link", desc.mount.child_link),
        ):
            if name not in links:
                raise fail(f"mount.{key}: the URDF has no link {name!r}")
    if desc.palm_link not in links:
        raise fail(f"palm.link: the URDF has no link {desc.palm_link!r}")
    for link, _ in desc.link_groups:
        if link not in links:
            raise fail(f"grip.link_groups: the URDF has no link {link!r}")
    finger_names = {fj.name for fj in desc.finger_joints}
    limits: list[tuple[str, float, float]] = []
    for fi, finger in enumerate(desc.fingers):
        for ji, fj in enumerate(finger.joints):
            at = f"fingers[{fi}].joints[{ji}]"
            j = joints.get(fj.name)
            if j is None:
                raise fail(f"fingers: {missing(fj.name)}")
            if j.type not in ("revolute", "prismatic"):
                raise fail(f"fingers: joint {fj.name!r} is {j.type}, not revolute or prismatic")
            lim = j.limits
            if lim is None:
                continue
            limits.append((fj.name, lim[0], lim[1]))
            for key, q in (("open", fj.open), ("closed", fj.closed)):
                if not lim[0] - 1e-9 <= q <= lim[1] + 1e-9:
                    raise fail(
                        f"{at}.{key} {q:g} is outside {fj.name!r}'s URDF limits "
                        f"[{lim[0]:g}, {lim[1]:g}]"
                    )
    mimics = []
    for n, j in joints.items():
        if j.mimic is None or j.type not in ("revolute", "prismatic") or n in finger_names:
            continue  # a mimic the description lists is driven as listed
        owner = model if n in model.joints else models[-1]
        master, m, o = owner.mimic_root(n, frozenset(finger_names))
        if master in finger_names:
            mimics.append(MimicJoint(n, master, m, o, j.lower, j.upper))
    prismatic = frozenset(
        fj.name for fj in desc.finger_joints if joints[fj.name].type == "prismatic"
    )
    return dataclasses.replace(
        desc,
        prismatic_joints=prismatic,
        mimic_joints=tuple(mimics),
        finger_limits=tuple(limits),
    )
