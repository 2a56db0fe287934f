"""The one URDF reader: what dsteleop takes from a URDF is read here and nowhere else.

`robot.description` checks a description against its URDFs, `robot.model` assembles the
text PyBullet loads, `robot.kinematics` reads the arm's chain; all three read through
`UrdfModel`. No PyBullet here: a description loads without a physics client.

**Joints and links are the robot's top-level `<joint>` and `<link>` children**, as the
URDF specification and PyBullet's own parser have it. A ROS URDF's `<transmission>` blocks
hold `<joint name="...">` entries too (the joint an actuator drives: no type, no origin, no
limits), and `<gazebo>` blocks may name joints; a recursive search finds those and lets
them replace the real joint (the user then read "'joint1' is None, not revolute" about a
revolute joint). They are not joints; their names are kept (`UrdfModel.named_elsewhere`)
only so that an error can say where a name was seen.

**Mimic joints.** `<mimic joint="J" multiplier="m" offset="o"/>` couples a joint to its
master J: q = m q_J + o (URDF defaults m = 1, o = 0). PyBullet ignores the tag, so the
robot drives each mimic joint from its master's command (`robot.arm`); `mimic_root` follows
a chain of mimics to the joint that is not one, composing the couplings.

**Meshes** (`resolve_meshes`). A `<mesh filename>` is resolved to an absolute file:

    package://NAME/REST   for each directory D of the search path, in order: D/NAME/REST,
                          or D/REST when D itself is the package NAME (ROS_PACKAGE_PATH
                          semantics: a directory of packages, or a package); then the URDF's
                          own package: the nearest folder above the URDF named NAME; then
                          beside the URDF: URDF_DIR/NAME/REST (pybullet_data's URDFs write
                          package://meshes/... for their own meshes folder)
    file:///ABS           the absolute path
    ABS                   itself
    REL                   URDF_DIR/REL (the URDF specification), then D/REL for each D

The search path (`package_search_path`) is the description's `package_path` (folders
relative to the description file), then `ROS_PACKAGE_PATH` (colon-separated), then each
`AMENT_PREFIX_PATH` prefix's `share` folder (a ROS 2 install). A mesh found nowhere is one
`InputError` naming the file and every folder searched.

**Inertia** (`repair_inertia`). PyBullet zeroes a link's inertia tensor whose principal
moments are negative or break the triangle inequality (each at most the sum of the other
two), and prints "Bad inertia tensor properties" at every load (12 times a run). Such a
tensor is repaired before PyBullet sees it: negative moments become 0, and when the largest
exceeds the sum of the other two, those two are raised by half the excess each (the largest
moment, the one that dominates the link's dynamics, is kept). The caller logs the repair
once per process and link.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import InputError

Array = NDArray[np.float64]

PACKAGE_PREFIX = "package://"
FILE_PREFIX = "file://"
#: PyBullet's test is strict (0.1 > 0.05 + 0.0499999 is refused); a repair is needed when
#: the triangle inequality fails by more than this share of the largest principal moment.
INERTIA_TOLERANCE = 1e-12


@dataclass(frozen=True)
class Mimic:
    """A joint's `<mimic>`: q = multiplier * q_joint + offset."""

    joint: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class UrdfJoint:
    """One top-level `<joint>`.

    Attributes:
        name: its name.
        type: its type attribute ("revolute", "prismatic", "fixed", "continuous", ...), or
            None when the element has none.
        parent: its parent link's name (None when missing).
        child: its child link's name (None when missing).
        T_parent_joint: (4, 4) its origin in the parent link's frame [m].
        axis: (3,) its axis in its own frame (URDF default x).
        lower: lower limit [rad or m] (URDF default 0), or None without a `<limit>`.
        upper: upper limit [rad or m], or None.
        mimic: its `<mimic>`, or None.
    """

    name: str
    type: str | None
    parent: str | None
    child: str | None
    T_parent_joint: Array
    axis: Array
    lower: float | None
    upper: float | None
    mimic: Mimic | None

    @property
    def limits(self) -> tuple[float, float] | None:
        """(lower, upper), or None when the URDF gives no limits."""
        if self.lower is None or self.upper is None:
            return None
        return (self.lower, self.upper)


def rpy_to_R(r: float, p: float, y: float) -> Array:
    """The rotation of URDF roll-pitch-yaw angles (fixed axes x, y, z) [rad]."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _floats(text: str | None, n: int, default: str, what: str) -> list[float]:
    parts = (text if text is not None else default).split()
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        raise InputError(f"{what}: not {n} numbers: {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise InputError(f"{what}: not {n} finite numbers: {text!r}")
    return vals


def _origin(el: ET.Element, what: str) -> Array:
    T = np.eye(4)
    o = el.find("origin")
    if o is not None:
        T[:3, :3] = rpy_to_R(*_floats(o.get("rpy"), 3, "0 0 0", f"{what} <origin rpy>"))
        T[:3, 3] = _floats(o.get("xyz"), 3, "0 0 0", f"{what} <origin xyz>")
    return T


def _opt_float(el: ET.Element | None, key: str, what: str) -> float | None:
    """A `<limit>` attribute: None without the element, the URDF default 0 without the
    attribute."""
    if el is None:
        return None
    return _floats(el.get(key), 1, "0", f"{what} {key}")[0]


def _joint(el: ET.Element, where: str) -> UrdfJoint:
    name = str(el.get("name"))
    what = f"{where}: joint {name!r}"
    parent, child, ax, lim, mim = (
        el.find(k) for k in ("parent", "child", "axis", "limit", "mimic")
    )
    axis = np.array(
        _floats(ax.get("xyz") if ax is not None else None, 3, "1 0 0", f"{what} <axis>")
    )
    mimic = None
    if mim is not None:
        if not mim.get("joint"):
            raise InputError(f"{what}: <mimic> names no joint")
        mimic = Mimic(
            str(mim.get("joint")),
            _floats(mim.get("multiplier"), 1, "1", f"{what} <mimic multiplier>")[0],
            _floats(mim.get("offset"), 1, "0", f"{what} <mimic offset>")[0],
        )
    if el.get("type") == "continuous":  # unlimited, whatever its <limit> says
        lim = None
    return UrdfJoint(
        name=name,
        type=el.get("type"),
        parent=parent.get("link") if parent is not None else None,
        child=child.get("link") if child is not None else None,
        T_parent_joint=_origin(el, what),
        axis=axis,
        lower=_opt_float(lim, "lower", f"{what} <limit>"),
        upper=_opt_float(lim, "upper", f"{what} <limit>"),
        mimic=mimic,
    )


def no_joint(name: str, named_elsewhere: frozenset[str] = frozenset()) -> str:
    """ "the URDF has no joint NAME", saying when only a transmission (or such) names it."""
    if name in named_elsewhere:
        return (
            f"the URDF has no joint {name!r} (only a <transmission> or <gazebo> block names "
            "it; a joint is a top-level <joint>)"
        )
    return f"the URDF has no joint {name!r}"


class UrdfModel:
    """A parsed URDF: its top-level joints and links (module docstring).

    Args:
        root: the `<robot>` element (kept: `robot.model` edits and writes it).
        path: the file it came from, or None (text).
        where: how errors name it ("URDF /path/arm.urdf").
    """

    def __init__(self, root: ET.Element, path: Path | None = None, where: str = "URDF") -> None:
        if root.tag != "robot":
            raise InputError(f"{where}: the root element is <{root.tag}>, not <robot>")
        self.root, self.path, self.where = root, path, where
        self.joints: dict[str, UrdfJoint] = {}
        for el in root.findall("joint"):
            if not el.get("name"):
                raise InputError(f"{where}: a <joint> has no name")
            self.joints[str(el.get("name"))] = _joint(el, where)
        self.links: frozenset[str] = frozenset(
            str(ln.get("name")) for ln in root.findall("link") if ln.get("name")
        )
        top = set(root.findall("joint"))
        #: joint names found below the top level (in `<transmission>`, `<gazebo>`, ...)
        self.named_elsewhere: frozenset[str] = frozenset(
            str(j.get("name")) for j in root.iter("joint") if j not in top and j.get("name")
        )

    @classmethod
    def from_text(cls, text: str, where: str = "URDF") -> UrdfModel:
        """Parse URDF text.

        Raises:
            InputError: not XML, or not a URDF.
        """
        try:
            return cls(ET.fromstring(text), None, where)
        except ET.ParseError as exc:
            raise InputError(f"{where}: not valid XML ({exc})") from None

    @classmethod
    def read(cls, path: Path, where: str | None = None) -> UrdfModel:
        """Parse a URDF file.

        Raises:
            InputError: no such file, not XML, or not a URDF.
        """
        where = where or f"URDF {path}"
        if not path.is_file():
            raise InputError(f"{where}: no file {path}")
        try:
            return cls(ET.parse(path).getroot(), path, where)
        except ET.ParseError as exc:
            raise InputError(f"{where}: not valid XML ({exc})") from None
        except OSError as exc:
            raise InputError(f"{where}: cannot be read ({exc})") from None

    def missing_joint(self, name: str) -> str:
        """Why `name` is not a joint of this URDF, in a few words."""
        return no_joint(name, self.named_elsewhere)

    def mimic_root(
        self, name: str, drivers: frozenset[str] = frozenset()
    ) -> tuple[str, float, float]:
        """The joint a (chain of) mimic joint(s) follows and the composed coupling:
        (master, m, o) with q_name = m q_master + o; (name, 1, 0) for a joint that is no
        mimic. The chain stops at a joint of `drivers` (joints driven by their own command,
        whatever their `<mimic>`).

        Raises:
            InputError: a mimic names a joint the URDF lacks, or the mimics form a loop.
        """
        m, o, at, seen = 1.0, 0.0, name, {name}
        while (j := self.joints.get(at)) is not None and j.mimic is not None:
            if at != name and at in drivers:
                break
            nxt = j.mimic.joint
            if nxt not in self.joints:
                raise InputError(
                    f"{self.where}: joint {at!r} mimics {nxt!r}: {self.missing_joint(nxt)}"
                )
            if nxt in seen:
                raise InputError(f"{self.where}: the <mimic> joints {sorted(seen)} form a loop")
            seen.add(nxt)
            m, o = m * j.mimic.multiplier, o + m * j.mimic.offset
            at = nxt
        return at, m, o


def package_search_path(
    dirs: Iterable[Path] = (), env: Mapping[str, str] | None = None
) -> tuple[Path, ...]:
    """The folders `package://` and relative meshes are looked up in (module docstring):
    `dirs` (a description's `package_path`), then `ROS_PACKAGE_PATH`, then each
    `AMENT_PREFIX_PATH` prefix's `share`."""
    env = os.environ if env is None else env
    out = [Path(d) for d in dirs]
    out += [Path(d) for d in env.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if d]
    out += [Path(d) / "share" for d in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if d]
    return tuple(out)


def resolve_mesh(ref: str, urdf_path: Path, search: tuple[Path, ...]) -> Path | None:
    """The file a mesh reference names (module docstring), or None when none exists."""
    here = urdf_path.parent
    if ref.startswith(PACKAGE_PREFIX):
        name, _, rest = ref[len(PACKAGE_PREFIX) :].partition("/")
        candidates = []
        for d in search:
            candidates.append(d / name / rest)
            if d.name == name:
                candidates.append(d / rest)
        candidates += [a / rest for a in (here, *here.parents) if a.name == name][:1]
        candidates.append(here / name / rest)
    elif ref.startswith(FILE_PREFIX):
        candidates = [Path(ref[len(FILE_PREFIX) :])]
    elif Path(ref).is_absolute():
        candidates = [Path(ref)]
    else:
        candidates = [here / ref, *(d / ref for d in search)]
    return next((Path(os.path.abspath(c)) for c in candidates if c.is_file()), None)


def resolve_meshes(model: UrdfModel, search: tuple[Path, ...], where: str) -> None:
    """Rewrite every `<mesh filename>` of `model` (read from a file) to an absolute path.

    Raises:
        InputError: a mesh is found nowhere: one line naming it and the folders searched.
    """
    assert model.path is not None, "meshes resolve against the URDF's own file"
    for mesh in model.root.iter("mesh"):
        ref = mesh.get("filename", "")
        found = resolve_mesh(ref, model.path, search)
        if found is None:
            looked = [str(model.path.parent), *(str(d) for d in search)]
            raise InputError(
                f"{where}: mesh {ref!r} not found (searched {', '.join(looked)}; add its "
                "package's parent folder to package_path or ROS_PACKAGE_PATH)"
            )
        mesh.set("filename", str(found))


def principal_inertia(el: ET.Element) -> tuple[Array, Array] | None:
    """The principal moments (3,) and axes (3, 3, columns) of an `<inertia>` element."""
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    try:
        ixx, ixy, ixz, iyy, iyz, izz = (float(el.get(k, "0")) for k in keys)
    except ValueError:
        return None
    M = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if not np.isfinite(M).all():
        return None
    w, V = np.linalg.eigh(M)
    return w, V


def repair_inertia(el: ET.Element) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """Repair an `<inertia>` element PyBullet would zero (module docstring), in place.

    Returns:
        None when it needed nothing, else (the principal moments before, after) [kg m^2].
    """
    pi = principal_inertia(el)
    if pi is None:
        return None
    w, V = pi
    lam = np.maximum(w, 0.0)
    big = int(np.argmax(lam))
    others = [k for k in range(3) if k != big]
    excess = lam[big] - lam[others].sum()
    negative = bool((w < 0.0).any())
    if not negative and excess <= INERTIA_TOLERANCE * max(lam[big], 1e-300):
        return None
    if excess > 0.0:  # with a margin PyBullet's strict test survives in 12 digits
        lam[others] += excess / 2.0 + 1e-9 * lam[big]
    M = V @ np.diag(lam) @ V.T
    for k, (i, j) in zip(
        ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    ):
        el.set(k, f"{M[i, j]:.12g}")
    return tuple(float(x) for x in w), tuple(float(x) for x in lam)
