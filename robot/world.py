"""The kitchen pick-and-place world: table, utensil holder with utensils, bin, floor.

Layout in the robot base frame (x forward towards the table, y left, z up; metres); the table
top is the plane z = 0 (the robot's base stands at the table's near edge):

    table     x in [0.22, 1.02], y in [-0.70, 0.70], top at z = 0
    holder    centred at (0.58, +0.26): a bottom plate, low dividers, and a back rail at +y
              (0.12 m high) on two posts; three pockets along x, open towards -y (the bin
              side). The utensils stand in the pockets head down, leaning back ~5 deg on the
              rail, so a pull up and towards the bin frees them.
    bin       centred at (0.58, -0.26): inner 0.36 x 0.36 m, walls 0.08 m high
    floor     plane z = -0.75
    camera    the robot's own RGB-D camera, 1 m above the robot's base, looking down at the
              table between holder and bin (`perception.ROBOT_CAMERA_M`, kept there so the
              task imports no PyBullet): the robot perceives the utensils and the bin
              through it, 0.8-1.0 m away

The layout is written in the scene frame; a robot's placement (`robot.placement`: the
description's `[task]` table, or computed) stands the whole scene in its base frame
(`build_world(client, placement)`); the shipped robots' placement is the identity, so for
them the scene frame is the base frame and the numbers above are base-frame numbers.

Every object is built from primitives with `createMultiBody`; each body's base frame is its
centre-of-mass frame (no inertial offset), so the shapes below are placed relative to it and
a viewer can draw them from `getBasePositionAndOrientation` alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import matrix_from_quat_wxyz, quat_wxyz_from_matrix, so3_exp
from dsteleop.errors import ContractError
from dsteleop.robot.bullet import pb
from dsteleop.robot.placement import SHIPPED, Placement

Array = NDArray[np.float64]

TABLE_TOP_Z_M = 0.0
FLOOR_Z_M = -0.75
HOLDER_CENTER_M = (0.58, 0.26)
BIN_CENTER_M = (0.58, -0.26)
BIN_INNER_HALF_M = 0.18
BIN_WALL_HEIGHT_M = 0.08
BIN_FLOOR_M = 0.01
HOLDER_POCKET_PITCH_M = 0.075
HOLDER_RAIL_Y_M = 0.0335  # back rail centre, relative to the holder centre
HOLDER_RAIL_Z_M = 0.12  # back rail centre height
HOLDER_PLATE_M = 0.01
HOLDER_HALF_M = (0.12, 0.05)
UTENSIL_LENGTH_M = 0.28
UTENSIL_LEAN_RAD = 0.10  # initial backward lean (top towards +y); physics settles it

# Contact parameters (PyBullet changeDynamics). Fingers and grips: rubbery, high friction.
UTENSIL_FRICTION = 1.0
FINGER_FRICTION = 1.2
SURFACE_FRICTION = 0.6


PartKind = Literal["box", "sphere", "cylinder"]


def _vec3(a: Array) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class Part:
    """One primitive of a body, in the body's base (centre-of-mass) frame.

    Attributes:
        kind: "box", "sphere" or "cylinder" (cylinders along their local z).
        size_m: box: full extents (3,); sphere: (radius,); cylinder: (radius, length).
        p_body_part_m: (3,) position of the primitive's centre.
        R_body_part: (3, 3) orientation of the primitive.
        rgba: colour.
        mass_kg: this part's share of the body's mass (for the centre of mass).
    """

    kind: PartKind
    size_m: tuple[float, ...]
    p_body_part_m: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    mass_kg: float = 0.0
    R_body_part: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class UtensilSpec:
    """A utensil: parts in a frame at its bottom centre (z up along the handle)."""

    name: str
    parts: tuple[Part, ...]

    def com_m(self) -> Array:
        """Centre of mass in the bottom-centre frame [m]."""
        m = np.array([p.mass_kg for p in self.parts])
        x = np.array([p.p_body_part_m for p in self.parts])
        return np.asarray((m[:, None] * x).sum(0) / m.sum(), dtype=np.float64)

    @property
    def mass_kg(self) -> float:
        return float(sum(p.mass_kg for p in self.parts))


_GRIP = (0.045, 0.024, 0.08)  # the handle's grip section: wide along x, thin along y
_STEEL = (0.72, 0.74, 0.78, 1.0)
_WOOD = (0.55, 0.35, 0.18, 1.0)
_GRIP_Z = UTENSIL_LENGTH_M - _GRIP[2] / 2


def _grip(rgba: tuple[float, float, float, float]) -> Part:
    return Part("box", _GRIP, (0.0, 0.0, _GRIP_Z), rgba, 0.025)


UTENSILS: dict[str, UtensilSpec] = {
    "spoon": UtensilSpec(
        "spoon",
        (
            Part("box", (0.050, 0.012, 0.060), (0.0, 0.0, 0.030), _STEEL, 0.030),
            Part("box", (0.014, 0.008, 0.140), (0.0, 0.0, 0.130), _STEEL, 0.015),
            _grip((0.20, 0.45, 0.75, 1.0)),
        ),
    ),
    "spatula": UtensilSpec(
        "spatula",
        (
            Part("box", (0.055, 0.006, 0.080), (0.0, 0.0, 0.040), (0.15, 0.15, 0.15, 1.0), 0.030),
            Part("box", (0.014, 0.008, 0.120), (0.0, 0.0, 0.140), _STEEL, 0.012),
            _grip(_WOOD),
        ),
    ),
    "ladle": UtensilSpec(
        "ladle",
        (
            Part("sphere", (0.028,), (0.0, 0.0, 0.028), _STEEL, 0.050),
            Part("box", (0.012, 0.008, 0.144), (0.0, 0.0, 0.128), _STEEL, 0.015),
            _grip((0.75, 0.25, 0.20, 1.0)),
        ),
    ),
}
UTENSIL_NAMES: tuple[str, ...] = tuple(UTENSILS)


def T_utensil_grasp(
    spec: UtensilSpec, grasp_xyz_m: Sequence[float], grasp_depth_m: float
) -> tuple[Array, Array]:
    """The palm pose for grasping `spec`, in its centre-of-mass frame: (p [m], R).

    The robot's grasp frame (its tool centre point, `grasp_xyz_m` in the palm frame) sits
    on the grip's axis `grasp_depth_m` below the grip's top end (negative: above it), the
    palm pointing down the handle (palm z = -utensil z), its finger row along the grip's
    wide side (palm x = -utensil x, palm y = utensil y: the arm's natural wrist posture when
    the utensil stands upright), so the fingers (or a gripper's jaws) close on the grip's
    thin sides. The iiwa's hand: the grasp frame is the palm, 12 mm above the top; the
    Panda's: between its pads, inside the grip (docs/robots.md).
    """
    R = np.diag([-1.0, 1.0, -1.0])
    p_grasp = np.array([0.0, 0.0, UTENSIL_LENGTH_M - grasp_depth_m])
    p = p_grasp - R @ np.asarray(grasp_xyz_m, dtype=np.float64) - spec.com_m()
    return p, R


def quat_xyzw_from_R(R: Array) -> tuple[float, float, float, float]:
    """PyBullet's xyzw quaternion of a rotation matrix (the boundary's order)."""
    w, x, y, z = (float(v) for v in quat_wxyz_from_matrix(R))
    return (x, y, z, w)


def quat_wxyz_from_R(R: Array) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix."""
    w, x, y, z = (float(v) for v in quat_wxyz_from_matrix(R))
    return (w, x, y, z)


def R_from_quat_xyzw(q: tuple[float, ...] | list[float]) -> Array:
    """Rotation matrix of PyBullet's xyzw quaternion."""
    x, y, z, w = (float(v) for v in q)
    return matrix_from_quat_wxyz(np.array([w, x, y, z]))


@dataclass
class WorldBodies:
    """Body ids of the built world, and each body's parts (for the viewer)."""

    table: int
    holder: int
    bin: int
    floor: int
    utensils: dict[str, int]
    parts: dict[int, tuple[Part, ...]] = field(default_factory=dict)
    names: dict[int, str] = field(default_factory=dict)


def _shape_args(parts: tuple[Part, ...]) -> dict[str, list[object]]:
    types, half, radii, lengths, pos, orn = [], [], [], [], [], []
    for p in parts:
        if p.kind == "box":
            types.append(pb.GEOM_BOX)
            half.append([s / 2 for s in p.size_m])
            radii.append(0.0)
            lengths.append(0.0)
        elif p.kind == "sphere":
            types.append(pb.GEOM_SPHERE)
            half.append([0.0, 0.0, 0.0])
            radii.append(p.size_m[0])
            lengths.append(0.0)
        elif p.kind == "cylinder":
            types.append(pb.GEOM_CYLINDER)
            half.append([0.0, 0.0, 0.0])
            radii.append(p.size_m[0])
            lengths.append(p.size_m[1])
        else:  # pragma: no cover - specs are constants
            raise ContractError(p.kind)
        pos.append(list(p.p_body_part_m))
        orn.append(list(quat_xyzw_from_R(np.array(p.R_body_part))))
    return {
        "shapeTypes": types,
        "halfExtents": half,
        "radii": radii,
        "lengths": lengths,
        "frame_pos": pos,
        "frame_orn": orn,
    }


def _compound(
    client: int,
    parts: tuple[Part, ...],
    mass_kg: float,
    p_base_body_m: Array,
    R_base_body: Array,
) -> int:
    a = _shape_args(parts)
    col = pb.createCollisionShapeArray(
        shapeTypes=a["shapeTypes"],
        halfExtents=a["halfExtents"],
        radii=a["radii"],
        lengths=a["lengths"],
        collisionFramePositions=a["frame_pos"],
        collisionFrameOrientations=a["frame_orn"],
        physicsClientId=client,
    )
    vis = pb.createVisualShapeArray(
        shapeTypes=a["shapeTypes"],
        halfExtents=a["halfExtents"],
        radii=a["radii"],
        lengths=a["lengths"],
        visualFramePositions=a["frame_pos"],
        visualFrameOrientations=a["frame_orn"],
        rgbaColors=[list(p.rgba) for p in parts],
        physicsClientId=client,
    )
    return int(
        pb.createMultiBody(
            baseMass=mass_kg,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=[float(v) for v in p_base_body_m],
            baseOrientation=quat_xyzw_from_R(R_base_body),
            physicsClientId=client,
        )
    )


def _box(
    size: tuple[float, float, float],
    center: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
) -> Part:
    return Part("box", size, center, rgba)


def holder_parts() -> tuple[Part, ...]:
    """The holder's boxes, relative to its centre on the table top."""
    hx, hy = HOLDER_HALF_M
    c = (0.93, 0.93, 0.90, 1.0)
    wall_t = 0.01
    rail_h = 0.015
    post_h = HOLDER_RAIL_Z_M - rail_h / 2
    parts = [
        _box((2 * hx, 2 * hy, HOLDER_PLATE_M), (0.0, 0.0, HOLDER_PLATE_M / 2), c),
        _box((2 * hx, wall_t, rail_h), (0.0, HOLDER_RAIL_Y_M, HOLDER_RAIL_Z_M), c),
        _box((wall_t, wall_t, post_h), (hx - wall_t / 2, HOLDER_RAIL_Y_M, post_h / 2), c),
        _box((wall_t, wall_t, post_h), (-hx + wall_t / 2, HOLDER_RAIL_Y_M, post_h / 2), c),
    ]
    for i in range(4):  # dividers and side walls between/around the three pockets
        x = (i - 1.5) * HOLDER_POCKET_PITCH_M
        parts.append(_box((wall_t, 2 * hy, 0.06), (x, 0.0, 0.03), c))
    return tuple(parts)


def bin_parts() -> tuple[Part, ...]:
    """The bin's floor and walls, relative to its centre on the table top."""
    h, t, H = BIN_INNER_HALF_M, 0.01, BIN_WALL_HEIGHT_M
    c = (0.25, 0.55, 0.35, 1.0)
    return (
        _box((2 * h + 2 * t, 2 * h + 2 * t, BIN_FLOOR_M), (0.0, 0.0, BIN_FLOOR_M / 2), c),
        _box((t, 2 * h + 2 * t, H), (h + t / 2, 0.0, H / 2), c),
        _box((t, 2 * h + 2 * t, H), (-h - t / 2, 0.0, H / 2), c),
        _box((2 * h, t, H), (0.0, h + t / 2, H / 2), c),
        _box((2 * h, t, H), (0.0, -h - t / 2, H / 2), c),
    )


def pocket_center_m(index: int) -> Array:
    """Centre of holder pocket `index` (0, 1, 2) on the holder plate, scene frame [m]."""
    return np.array(
        [
            HOLDER_CENTER_M[0] + (index - 1) * HOLDER_POCKET_PITCH_M,
            HOLDER_CENTER_M[1],
            TABLE_TOP_Z_M + HOLDER_PLATE_M,
        ]
    )


def utensil_start_pose(
    spec: UtensilSpec, index: int, placement: Placement = SHIPPED
) -> tuple[Array, Array]:
    """Initial COM pose of a utensil in its pocket, leaning back: (p [m], R), in the base
    frame of a robot that stands the scene at `placement`."""
    R = so3_exp(np.array([-UTENSIL_LEAN_RAD, 0.0, 0.0]))  # top towards +y
    bottom = pocket_center_m(index) + np.array([0.0, 0.012, 0.002])
    return placement.pose(bottom + R @ spec.com_m(), R)


def build_world(client: int, placement: Placement = SHIPPED) -> WorldBodies:
    """Create the static scene and the utensils in `client` (dynamics set, not settled),
    the scene stood at `placement` in the base frame (module docstring)."""
    table_parts = (_box((0.80, 1.40, 0.04), (0.0, 0.0, 0.0), (0.80, 0.70, 0.50, 1.0)),)
    R = placement.rotation(np.eye(3))
    table = _compound(
        client,
        table_parts,
        0.0,
        placement.point(np.array([0.62, 0.0, TABLE_TOP_Z_M - 0.02])),
        R,
    )
    hc = placement.point(np.array([HOLDER_CENTER_M[0], HOLDER_CENTER_M[1], TABLE_TOP_Z_M]))
    holder = _compound(client, holder_parts(), 0.0, hc, R)
    bc = placement.point(np.array([BIN_CENTER_M[0], BIN_CENTER_M[1], TABLE_TOP_Z_M]))
    bin_ = _compound(client, bin_parts(), 0.0, bc, R)
    plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client)
    p_floor = [float(v) for v in placement.point(np.array([0.0, 0.0, FLOOR_Z_M]))]
    floor = int(pb.createMultiBody(0.0, plane, -1, p_floor, physicsClientId=client))
    bodies = WorldBodies(table, holder, bin_, floor, {})
    bodies.parts.update({table: table_parts, holder: holder_parts(), bin_: bin_parts()})
    bodies.names.update({table: "table", holder: "holder", bin_: "bin", floor: "floor"})
    for i, (name, spec) in enumerate(UTENSILS.items()):
        com = spec.com_m()
        parts = tuple(
            Part(
                p.kind,
                p.size_m,
                _vec3(np.asarray(p.p_body_part_m) - com),
                p.rgba,
                p.mass_kg,
                p.R_body_part,
            )
            for p in spec.parts
        )
        p0, R0 = utensil_start_pose(spec, i, placement)
        uid = _compound(client, parts, spec.mass_kg, p0, R0)
        pb.changeDynamics(
            uid,
            -1,
            lateralFriction=UTENSIL_FRICTION,
            rollingFriction=0.0,
            spinningFriction=0.002,
            restitution=0.0,
            physicsClientId=client,
        )
        bodies.utensils[name] = uid
        bodies.parts[uid] = parts
        bodies.names[uid] = name
    for b in (table, holder, bin_, floor):
        pb.changeDynamics(
            b, -1, lateralFriction=SURFACE_FRICTION, restitution=0.0, physicsClientId=client
        )
    return bodies
