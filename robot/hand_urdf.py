"""The project's multi-finger hand as a URDF (primitive shapes), and the script that writes it.

`python -m dsteleop.robot.hand_urdf` regenerates `robot/assets/dsteleop_hand.urdf`; a test
checks that the committed file equals the generated text (golden file next to its script).

Frames (see docs/robot.md): the `palm` link frame sits at the centre of the palm's inner
face; +z is the palm normal, the direction the fingers point when open (the approach
direction); the fingers `index`, `middle`, `ring` stand in a row along x at y < 0 and the
`thumb` opposes them at y > 0. Each finger has two revolute joints, `<finger>_mcp` and
`<finger>_pip`, that move by equal and opposite angles, so the distal pad stays parallel to
the palm normal and closes like a parallel jaw. Open and closed angles are
`JOINT_OPEN_CLOSED_RAD` (the URDF limits are the same two values, lower first): openness 1 ->
open, 0 -> closed, linear in between (see `robot.arm`).

Visual shapes are boxes; each phalanx collides as the capsule inscribed in its box (a pad on
a flat face makes two contact points instead of four: about half the solver work of a grasp).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

FINGER_NAMES: tuple[str, ...] = ("thumb", "index", "middle", "ring")
"""The robot's fingers, in the order of the openness vector (CONVENTIONS.md)."""

ASSET_PATH = Path(__file__).resolve().parent / "assets" / "dsteleop_hand.urdf"
PALM_LINK = "palm"
MOUNT_PARENT_LINK = "lbr_iiwa_link_7"


@dataclass(frozen=True)
class _Finger:
    name: str
    p_palm_base_m: tuple[float, float, float]
    flex_sign: float  # +1 closes towards +y (fingers), -1 towards -y (thumb)
    proximal_m: float
    distal_m: float
    rgba: str


_PALM_SIZE_M = (0.090, 0.075, 0.030)
_PALM_MASS_KG = 0.4
_FINGER_WIDTH_M = 0.023  # along x (1 mm gaps: nothing wedges between fingers)
_FINGER_DEPTH_M = 0.016  # along y
_PROXIMAL_KG = 0.03
_DISTAL_KG = 0.02
# (open, closed) joint angles [rad]. The two joints of a finger move in opposite senses by the
# same angle (pip = -mcp): a parallelogram-like finger whose distal pad stays parallel to the
# palm normal and presses flat on the object (a face contact grips far better than a tip).
MCP_OPEN_CLOSED_RAD = (-0.45, 0.55)
PIP_OPEN_CLOSED_RAD = (0.45, -0.55)
_EFFORT_NM = 2.0
PAD_CAPSULES = True
JOINT_OPEN_CLOSED_RAD: dict[str, tuple[float, float]] = {
    f"{f}_{j}": oc
    for f in FINGER_NAMES
    for j, oc in (("mcp", MCP_OPEN_CLOSED_RAD), ("pip", PIP_OPEN_CLOSED_RAD))
}
"""Open and closed angle of every finger joint, by name [rad]."""
_VELOCITY_RADPS = 6.0

_FINGERS = (
    _Finger("thumb", (0.0, 0.024, 0.0), -1.0, 0.045, 0.040, "0.80 0.65 0.50 1"),
    _Finger("index", (0.024, -0.024, 0.0), 1.0, 0.050, 0.040, "0.85 0.85 0.85 1"),
    _Finger("middle", (0.0, -0.024, 0.0), 1.0, 0.050, 0.040, "0.85 0.85 0.85 1"),
    _Finger("ring", (-0.024, -0.024, 0.0), 1.0, 0.050, 0.040, "0.85 0.85 0.85 1"),
)


def _f(x: float) -> str:
    return f"{x:.6g}"


def _box_inertia(mass: float, sx: float, sy: float, sz: float) -> str:
    ixx = mass * (sy * sy + sz * sz) / 12.0
    iyy = mass * (sx * sx + sz * sz) / 12.0
    izz = mass * (sx * sx + sy * sy) / 12.0
    return f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/>'


def _box_link(
    name: str,
    size: tuple[float, float, float],
    center: tuple[float, float, float],
    mass: float,
    rgba: str,
    capsule: bool = False,
) -> str:
    xyz = " ".join(_f(c) for c in center)
    dims = " ".join(_f(s) for s in size)
    if capsule:  # a phalanx's pad: a capsule along z inscribed in the box (few contact points)
        r = size[1] / 2
        col = f'<capsule radius="{_f(r)}" length="{_f(size[2] - 2 * r)}"/>'
    else:
        col = f'<box size="{dims}"/>'
    return f"""  <link name="{name}">
    <inertial>
      <origin xyz="{xyz}" rpy="0 0 0"/>
      <mass value="{_f(mass)}"/>
      {_box_inertia(mass, *size)}
    </inertial>
    <visual>
      <origin xyz="{xyz}" rpy="0 0 0"/>
      <geometry><box size="{dims}"/></geometry>
      <material name="{name}_color"><color rgba="{rgba}"/></material>
    </visual>
    <collision>
      <origin xyz="{xyz}" rpy="0 0 0"/>
      <geometry>{col}</geometry>
    </collision>
  </link>
"""


_LIMIT_TAIL = f'effort="{_f(_EFFORT_NM)}" velocity="{_f(_VELOCITY_RADPS)}"'


def _joint(
    name: str,
    parent: str,
    child: str,
    xyz: tuple[float, float, float],
    axis_sign: float,
    limits: tuple[float, float],
) -> str:
    return f"""  <joint name="{name}" type="revolute">
    <parent link="{parent}"/>
    <child link="{child}"/>
    <origin xyz="{" ".join(_f(c) for c in xyz)}" rpy="0 0 0"/>
    <axis xyz="{_f(-axis_sign)} 0 0"/>
    <limit lower="{_f(min(limits))}" upper="{_f(max(limits))}" {_LIMIT_TAIL}/>
    <dynamics damping="0.01" friction="0"/>
  </joint>
"""


def build_hand_urdf() -> str:
    """The hand's URDF text: root link `palm`, four two-joint fingers (primitive boxes)."""
    sx, sy, sz = _PALM_SIZE_M
    parts = [
        '<?xml version="1.0"?>\n',
        "<!-- Generated by `python -m dsteleop.robot.hand_urdf`; do not edit by hand. -->\n",
        '<robot name="dsteleop_hand">\n',
        _box_link(
            PALM_LINK, _PALM_SIZE_M, (0.0, 0.0, -sz / 2.0), _PALM_MASS_KG, "0.25 0.25 0.28 1"
        ),
    ]
    w, d = _FINGER_WIDTH_M, _FINGER_DEPTH_M
    for fin in _FINGERS:
        prox, dist = f"{fin.name}_proximal", f"{fin.name}_distal"
        parts.append(
            _joint(
                f"{fin.name}_mcp",
                PALM_LINK,
                prox,
                fin.p_palm_base_m,
                fin.flex_sign,
                MCP_OPEN_CLOSED_RAD,
            )
        )
        parts.append(
            _box_link(
                prox,
                (w, d, fin.proximal_m),
                (0, 0, fin.proximal_m / 2),
                _PROXIMAL_KG,
                fin.rgba,
                capsule=PAD_CAPSULES,
            )
        )
        parts.append(
            _joint(
                f"{fin.name}_pip",
                prox,
                dist,
                (0.0, 0.0, fin.proximal_m),
                fin.flex_sign,
                PIP_OPEN_CLOSED_RAD,
            )
        )
        parts.append(
            _box_link(
                dist,
                (w, d, fin.distal_m),
                (0, 0, fin.distal_m / 2),
                _DISTAL_KG,
                fin.rgba,
                capsule=PAD_CAPSULES,
            )
        )
    parts.append("</robot>\n")
    del sx, sy
    return "".join(parts)


def main() -> int:
    """Write the hand URDF next to this module (robot/assets/)."""
    ASSET_PATH.write_text(build_hand_urdf())
    sys.stderr.write(f"wrote {ASSET_PATH}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
