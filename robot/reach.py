"""Can a robot reach the kitchen task, and where should the task's scene stand for it?

The task's poses are each utensil's grasp pose in its pocket (the palm pose that puts the
robot's grasp frame on the grip, `world.T_utensil_grasp`, at the utensil's start pose) and
the place pose (the palm down above the bin), each at its grasp orientation, plus the
robot's home (`[home]`, its own, in the base frame). A pose is reachable when the arm's
inverse kinematics (`kinematics.ArmChain.ik`, many iterations, from the rest posture and a
few other starts) gets within `RobotConfig.unreachable_tol_m` and `unreachable_tol_rad` of it
and the pose lies in the description's workspace (`[limits]`: the box and the reach sphere
that every palm target is clamped into).

`task_placement` decides where the scene stands (`robot.placement`): the description's
`[task]` table when it has one; else the shipped layout when every pose is reachable there
(so the iiwa and the Panda keep theirs, untransformed); else the first of `SEARCH` (the scene
moved towards or away from the base and down or up, smallest moves first, yaw 0) where every
pose is reachable with room to spare: also `SEARCH_MARGIN_M` off along each base axis (the
robot's goal noise and a person's misses); else the shipped layout, which `problems` then
reports and `require_reachable` refuses (one line naming the pose, the error and the fix).
The search moves the scene along x and z only: the kitchen is symmetric about the base's x
axis (holder at y = +0.26 m, bin at -0.26 m), so a move along y brings one end nearer and
takes the other as far away, and a yaw turns every pose about the base's first joint axis,
which leaves each one's distance from the shoulder as it was. A robot whose first joint
cannot turn to one side, or stands beside the table, says where with `[task]`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import so3_exp
from dsteleop.errors import InputError
from dsteleop.robot.arm import RobotConfig, Workspace
from dsteleop.robot.description import RobotDescription
from dsteleop.robot.kinematics import ArmChain
from dsteleop.robot.placement import SHIPPED, Placement
from dsteleop.robot.world import (
    BIN_CENTER_M,
    UTENSIL_NAMES,
    UTENSILS,
    T_utensil_grasp,
    utensil_start_pose,
)

Array = NDArray[np.float64]

#: Palm pointing down (palm z = -base z), finger row along base x: the place orientation.
R_PALM_DOWN = np.diag([-1.0, 1.0, -1.0])
#: The place goal: the palm above the bin's centre, scene frame [m].
PLACE_POSITION_M = (BIN_CENTER_M[0], BIN_CENTER_M[1], 0.45)
#: The scene's moves the search tries (x towards (-) or away from (+) the base, z down (-)
#: or up (+)) [m], each pair ordered by its length, then x before z.
_DX_M = (0.0, -0.05, -0.10, -0.15, -0.20, -0.25, -0.30, 0.05, 0.10, 0.15)
_DZ_M = (0.0, -0.05, -0.10, -0.15, -0.20, -0.25, 0.05, 0.10)
SEARCH: tuple[tuple[float, float], ...] = tuple(
    sorted(((dx, dz) for dx in _DX_M for dz in _DZ_M), key=lambda m: (math.hypot(*m), -abs(m[0])))
)
#: A computed placement has room: each pose this far off along each base axis is reachable.
SEARCH_MARGIN_M = 0.02


@dataclass(frozen=True)
class PoseReach:
    """How near the arm gets to one task pose.

    Attributes:
        name: "grasp spoon", ..., "place", "home".
        position_m: (3,) the pose's position in the base frame [m].
        rotation: (3, 3) its orientation.
        error_m: the IK's remaining position error [m].
        error_rad: its remaining orientation error [rad].
        q_rad: the IK's joint positions [rad].
        outside: why the pose is outside the workspace (`[limits]`), or "".
        reachable: within the tolerances and the workspace.
    """

    name: str
    position_m: Array
    rotation: Array
    error_m: float
    error_rad: float
    q_rad: Array
    outside: str
    reachable: bool


def scene_poses(desc: RobotDescription, placement: Placement) -> dict[str, tuple[Array, Array]]:
    """The task's poses in the base frame at `placement` (module docstring), by name; the
    home last."""
    out: dict[str, tuple[Array, Array]] = {}
    for i, name in enumerate(UTENSIL_NAMES):
        spec = UTENSILS[name]
        p_u, R_u = utensil_start_pose(spec, i, placement)
        p_g, R_g = T_utensil_grasp(spec, desc.grasp_xyz_m, desc.grasp_depth_m)
        out[f"grasp {name}"] = (p_u + R_u @ p_g, R_u @ R_g)
    out["place"] = placement.pose(np.array(PLACE_POSITION_M), R_PALM_DOWN)
    return out


def home_pose(desc: RobotDescription) -> tuple[Array, Array]:
    """The robot's home (base frame)."""
    R = so3_exp(np.asarray(desc.home_rotvec_rad, dtype=np.float64))
    return np.array(desc.home_position_m, dtype=np.float64), np.where(np.abs(R) < 1e-12, 0.0, R)


def _starts(chain: ArmChain, desc: RobotDescription) -> list[Array]:
    rest = np.array(desc.rest_posture_rad, dtype=np.float64)
    mid = 0.5 * (chain.lower_rad + chain.upper_rad)
    mid = np.where(np.isfinite(mid), mid, 0.0)
    return [rest, 0.5 * (rest + mid), mid]


def reach_pose(
    chain: ArmChain,
    desc: RobotDescription,
    name: str,
    pose: tuple[Array, Array],
    config: RobotConfig | None = None,
    tol_scale: float = 1.0,
) -> PoseReach:
    """How near the arm gets to `pose` (module docstring); `tol_scale` scales the
    tolerances (a search wants room to spare)."""
    cfg = config or RobotConfig()
    p, R = pose
    rest = np.array(desc.rest_posture_rad, dtype=np.float64)
    best = None
    tol_m, tol_rad = cfg.unreachable_tol_m * tol_scale, cfg.unreachable_tol_rad * tol_scale
    for q0 in _starts(chain, desc):
        res = chain.ik(p, R, q0, rest, iterations=300, tol_m=1e-5, tol_rad=1e-4)
        if best is None or res.error_m + 0.1 * res.error_rad < best.error_m + 0.1 * best.error_rad:
            best = res
        if res.error_m <= tol_m and res.error_rad <= tol_rad:
            break
    assert best is not None
    outside = _outside(Workspace.of(desc), p)
    ok = best.error_m <= tol_m and best.error_rad <= tol_rad and not outside
    return PoseReach(name, p, R, best.error_m, best.error_rad, best.q_rad, outside, ok)


def _outside(ws: Workspace, p: Array) -> str:
    lo, hi = np.array(ws.lower_m), np.array(ws.upper_m)
    if (p < lo - 1e-9).any() or (p > hi + 1e-9).any():
        return "outside the workspace box (limits.workspace_min_m / workspace_max_m)"
    r = float(np.linalg.norm(p - np.array(ws.shoulder_m)))
    if r > ws.reach_m + 1e-9:
        return f"{r:.3f} m from the shoulder, beyond limits.reach_m {ws.reach_m:g}"
    return ""


def reach_all(
    chain: ArmChain,
    desc: RobotDescription,
    placement: Placement,
    config: RobotConfig | None = None,
    home: bool = True,
) -> list[PoseReach]:
    """Every task pose at `placement` (and the home), how near the arm gets to each."""
    poses = scene_poses(desc, placement)
    if home:
        poses["home"] = home_pose(desc)
    return [reach_pose(chain, desc, n, pose, config) for n, pose in poses.items()]


def _roomy(chain: ArmChain, desc: RobotDescription, placement: Placement, cfg: RobotConfig) -> bool:
    """Every task pose at `placement`, and each `SEARCH_MARGIN_M` off along each axis, is
    reachable (the home is the description's own: not the placement's business)."""
    for name, (p, R) in scene_poses(desc, placement).items():
        for k in range(7):
            dp = np.zeros(3)
            if k:
                dp[(k - 1) // 2] = SEARCH_MARGIN_M * (1 if k % 2 else -1)
            if not reach_pose(chain, desc, name, (p + dp, R), cfg, tol_scale=0.1).reachable:
                return False
    return True


def arm_chain(desc: RobotDescription) -> ArmChain:
    """The arm's kinematic chain, base to palm, read from the description's URDF(s)."""
    from dsteleop.robot.model import palm_tip_joints, robot_urdf_text

    text = robot_urdf_text(desc)
    return ArmChain.from_urdf(text, desc.arm_joints, palm_tip_joints(desc, text))


def task_placement(desc: RobotDescription, config: RobotConfig | None = None) -> Placement:
    """Where the task's scene stands for this robot (module docstring); computed once per
    description and tolerances in a process."""
    given = desc.task_placement
    if given is not None:
        return given
    cfg = config or RobotConfig()
    return _computed(desc, cfg.unreachable_tol_m, cfg.unreachable_tol_rad)


@functools.lru_cache(maxsize=16)
def _computed(desc: RobotDescription, tol_m: float, tol_rad: float) -> Placement:
    cfg = RobotConfig(unreachable_tol_m=tol_m, unreachable_tol_rad=tol_rad)
    chain = arm_chain(desc)
    if all(r.reachable for r in reach_all(chain, desc, SHIPPED, cfg, home=False)):
        return SHIPPED
    for dx, dz in SEARCH[1:]:
        candidate = Placement((dx, 0.0, dz), 0.0, "computed")
        if _roomy(chain, desc, candidate, cfg):
            return candidate
    return SHIPPED


def problems(desc: RobotDescription, placement: Placement, reaches: list[PoseReach]) -> list[str]:
    """Each unreachable pose as one line with its error and the fix."""
    out = []
    for r in reaches:
        if r.reachable:
            continue
        what = (
            r.outside
            if r.outside
            else f"IK error {1e3 * r.error_m:.1f} mm / {math.degrees(r.error_rad):.1f} deg"
        )
        if r.name == "home":
            fix = "set [home] position_m / rotvec_rad to a pose the arm reaches"
        elif r.outside:
            fix = "widen [limits] (workspace box, reach_m) or move the scene with [task] xyz_m"
        elif placement.source == "description":
            fix = "change [task] xyz_m / yaw_rad (or remove [task]: the placement is computed)"
        else:
            fix = (
                "set [task] xyz_m (and yaw_rad) to stand the scene where the arm reaches "
                "(no computed placement reaches every pose)"
            )
        p = ", ".join(f"{v:.3f}" for v in r.position_m)
        out.append(
            f"{r.name} at ({p}) m is not reachable at its grasp orientation: {what}; fix: {fix}"
        )
    return out


def require_reachable(
    desc: RobotDescription,
    config: RobotConfig | None = None,
    placement: Placement | None = None,
) -> Placement:
    """The task's placement for `desc` (or `placement`: a recorded one), when every task
    pose is reachable there: what `run`, `serve` and `replay` check before anything runs.

    Raises:
        InputError: the first unreachable pose, its error and the fix (one line).
    """
    placement = placement or task_placement(desc, config)
    found = problems(desc, placement, reach_all(arm_chain(desc), desc, placement, config))
    if found:
        raise InputError(f"robot description {desc.path}: {found[0]}")
    return placement
