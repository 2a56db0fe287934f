"""The kitchen environment: robot + world + task in one PyBullet DIRECT client.

The control loop drives it exactly like this (30 Hz, dt = 1/30 s; a loop at another rate
builds it with `RobotConfig.for_period(1 / rate)`, and each step is then 1/rate s):

    env = KitchenEnv()
    state = env.reset(utensil="spoon", seed=0)
    while env.task.outcome is None:
        step = arbiter.step(...)  # X_goal = env.task.goal, X_start = env.task.X_start
        env.set_target(step.X_next.position, step.X_next.rotation, step.X_next.openness)
        state = env.step()        # dt of physics, then the task's bookkeeping
        X_current = state.palm

`reset` rebuilds the whole simulation (resetSimulation + load), so the same seed and the same
commands give the same run bit for bit. A viewer calls `geometry()` once per reset and
`poses()` each tick.

The robot is any robot description (`EnvConfig.description`, default the iiwa). `step()` is
the two halves `step_robot()` (the physics of one tick) and `observe_task()` (the task's
bookkeeping); a task judging a robot outside this world drives the robot here as a twin of
the measured one instead (`follow`, docs/ARCHITECTURE.md).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import so3_exp
from dsteleop.errors import ConfigError, InputError
from dsteleop.robot.arm import BulletArm, BulletArmState, RobotConfig
from dsteleop.robot.bullet import pb
from dsteleop.robot.description import RobotDescription, load_description
from dsteleop.robot.kinematics import ArmChain
from dsteleop.robot.model import LoadedRobot, load_robot, palm_tip_joints, robot_urdf_text
from dsteleop.robot.perception import PerceptionError
from dsteleop.robot.placement import Placement
from dsteleop.robot.reach import PLACE_POSITION_M, task_placement
from dsteleop.robot.scene import SceneGeometry, ScenePoses, VisualGeometry, VisualKind
from dsteleop.robot.task import (
    Phase,
    PickPlaceTask,
    Region,
    SceneRegions,
    TaskConfig,
    TaskEvent,
    TaskObservation,
)
from dsteleop.robot.world import (
    BIN_CENTER_M,
    BIN_INNER_HALF_M,
    FLOOR_Z_M,
    HOLDER_CENTER_M,
    HOLDER_HALF_M,
    TABLE_TOP_Z_M,
    UTENSIL_NAMES,
    UTENSILS,
    R_from_quat_xyzw,
    T_utensil_grasp,
    WorldBodies,
    build_world,
    quat_wxyz_from_R,
)

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

GRAVITY_MPS2 = 9.81
R_PALM_DOWN = np.diag([-1.0, 1.0, -1.0])
"""Palm pointing down (palm z = -base z), finger row along base x: the home orientation."""


@dataclass(frozen=True)
class EnvConfig:
    """Environment settings.

    Attributes:
        robot: control and physics settings of the robot.
        task: task settings (goal noise, timeout, ...).
        place_position_m: true place goal: palm above the bin centre, scene frame [m]
            (`robot.placement`: the placement stands it in the base frame).
        settle_s: simulated time the scene settles after a reset, robot holding home [s].
        description: the robot (default: the iiwa with the four-finger hand).
        infer: the robot is not told its utensil: every utensil is a candidate goal
            (`PickPlaceTask.candidates_true`), and the task's utensil is the one grasped.
        perception: how the robot's known goals are drawn (None: isotropic, the task's
            goal noise; `robot.perception`).
        placement: where the task's scene stands in the base frame (`robot.placement`;
            None: the description's `[task]`, else computed, `robot.reach.task_placement`:
            the shipped robots' is the identity).
    """

    robot: RobotConfig = field(default_factory=RobotConfig)
    task: TaskConfig = field(default_factory=TaskConfig)
    place_position_m: tuple[float, float, float] = PLACE_POSITION_M
    settle_s: float = 1.0
    description: RobotDescription = field(default_factory=lambda: load_description("iiwa"))
    infer: bool = False
    perception: PerceptionError | None = None
    placement: Placement | None = None

    @property
    def home_position_m(self) -> tuple[float, float, float]:
        """Palm position at reset [m] (the robot's home, above the holder)."""
        return self.description.home_position_m

    @property
    def home_rotation(self) -> Array:
        """Palm orientation at reset (the robot's home: palm down for both shipped robots).
        Entries within 1e-12 of zero are zero, so a half or quarter turn is exact (the iiwa's
        palm-down home is exactly diag(-1, 1, -1), as it always was)."""
        R = so3_exp(np.asarray(self.description.home_rotvec_rad, dtype=np.float64))
        return np.where(np.abs(R) < 1e-12, 0.0, R)


def _regions(placement: Placement) -> SceneRegions:
    h = BIN_INNER_HALF_M
    bx, by = BIN_CENTER_M
    hx, hy = HOLDER_CENTER_M
    return SceneRegions(
        bin_inner=Region((bx - h, by - h, TABLE_TOP_Z_M), (bx + h, by + h, TABLE_TOP_Z_M + 0.4)),
        holder=Region(
            (hx - HOLDER_HALF_M[0], hy - HOLDER_HALF_M[1] - 0.02, TABLE_TOP_Z_M),
            (hx + HOLDER_HALF_M[0], hy + HOLDER_HALF_M[1] + 0.02, TABLE_TOP_Z_M + 0.4),
        ),
        floor_below_z_m=TABLE_TOP_Z_M - 0.1,
        placement=placement,
    )


class KitchenEnv:
    """Robot arm + hand, kitchen world and pick-and-place task (see module docstring).

    Args:
        config: environment settings.
    """

    def __init__(self, config: EnvConfig | None = None) -> None:
        self.config = config or EnvConfig()
        self._c = pb.connect(pb.DIRECT)
        desc = self.config.description
        self._urdf_text = robot_urdf_text(desc)
        self._chain = ArmChain.from_urdf(
            self._urdf_text, desc.arm_joints, palm_tip_joints(desc, self._urdf_text)
        )
        self.placement = self._placement_of(self.config)
        """Where the task's scene stands in the base frame (`robot.placement`)."""
        self._robot: BulletArm | None = None
        self._loaded: LoadedRobot | None = None
        self._world: WorldBodies | None = None
        self._task: PickPlaceTask | None = None
        self._geometry: SceneGeometry | None = None
        self._pose_links: list[int] = []
        self._pose_bodies: list[int] = []
        self.last_events: list[TaskEvent] = []
        """Events of the last `step()`."""

    @staticmethod
    def _placement_of(config: EnvConfig) -> Placement:
        if config.placement is not None:
            return config.placement
        return task_placement(config.description, config.robot)

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Disconnect the physics client."""
        if self._c >= 0:
            pb.disconnect(physicsClientId=self._c)
            self._c = -1

    def __enter__(self) -> KitchenEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset(self, utensil: str = "spoon", seed: int = 0) -> BulletArmState:
        """Rebuild the scene, settle it, and start a run for `utensil`.

        Args:
            utensil: one of `UTENSIL_NAMES`.
            seed: seed of the goal noise.

        Returns:
            The robot's state at the start of the run.

        Raises:
            ConfigError: for an unknown utensil.
        """
        if utensil not in UTENSILS:
            raise ConfigError(
                f"unknown utensil {utensil!r} (choose from {', '.join(UTENSIL_NAMES)})"
            )
        if self._c < 0:
            raise InputError("environment is closed")
        c = self._c
        if self.config.placement is not None:  # a new config may stand the scene elsewhere
            self.placement = self.config.placement
        pb.resetSimulation(physicsClientId=c)
        pb.setGravity(0.0, 0.0, -GRAVITY_MPS2, physicsClientId=c)
        self._loaded = load_robot(c, urdf_text=self._urdf_text)
        self._world = build_world(c, self.placement)
        self._robot = BulletArm(
            c,
            self._loaded,
            self._chain,
            self.config.robot,
            self.config.description,
            self._world.names,
            tuple(self._world.utensils.values()),
        )
        home = np.asarray(self.config.home_position_m, dtype=np.float64)
        n_fingers = len(self.config.description.fingers)
        self._robot.reset_posture(home, self.config.home_rotation, np.ones(n_fingers))
        for _ in range(round(self.config.settle_s / self.config.robot.control_dt_s)):
            self._robot.step()
        self._robot.reset_clock()
        pick = self._grasp_pose(utensil)
        place = self.placement.pose(
            np.asarray(self.config.place_position_m, dtype=np.float64), R_PALM_DOWN.copy()
        )
        candidates = {n: self._grasp_pose(n) for n in UTENSIL_NAMES} if self.config.infer else {}
        self._task = PickPlaceTask(
            self.config.task,
            utensil,
            pick,
            place,
            _regions(self.placement),
            n_fingers,
            seed,
            candidates_true=candidates,
            perception=self.config.perception,
        )
        state = self._robot.state()
        self._task.start(state.palm, state.t_s)
        self._geometry = None
        log.debug("reset: utensil=%s seed=%d", utensil, seed)
        return state

    # ------------------------------------------------------------------ access
    @property
    def robot(self) -> BulletArm:
        """The robot (after `reset`)."""
        if self._robot is None:
            raise InputError("call reset() first")
        return self._robot

    @property
    def task(self) -> PickPlaceTask:
        """The running task: goal, X_start, phase, events, outcome (after `reset`)."""
        if self._task is None:
            raise InputError("call reset() first")
        return self._task

    @property
    def world(self) -> WorldBodies:
        """Body ids of the scene (after `reset`)."""
        if self._world is None:
            raise InputError("call reset() first")
        return self._world

    @property
    def client(self) -> int:
        """PyBullet client id (for tests and tools inside `robot/`)."""
        return self._c

    @property
    def dt_s(self) -> float:
        """Control period [s]: the simulated time of one `step`."""
        return self.config.robot.control_dt_s

    # ------------------------------------------------------------------ control
    def set_target(self, position_m: Array, rotation: Array, openness: Array) -> None:
        """Command the palm pose and finger openness (see `BulletArm.set_target`)."""
        self.robot.set_target(position_m, rotation, openness)

    def step(self) -> BulletArmState:
        """One control tick: physics, then task bookkeeping. Returns the robot state."""
        self.step_robot()
        return self.observe_task()

    def step_robot(self) -> None:
        """The physics of one control tick under the current targets."""
        self.robot.step()

    def observe_task(self) -> BulletArmState:
        """The task's bookkeeping after the physics of a tick (`last_events`); returns the
        robot's state."""
        state = self.robot.state()
        self.last_events = self.task.update(self._observe(state))
        return state

    def follow(self, joint_positions: Mapping[str, float], openness: Array) -> None:
        """Drive the robot of this world towards measured joint positions (by name; the
        finger joints' too) with the measured finger command, and step one tick of physics:
        the twin of a robot that is not in this world (docs/ARCHITECTURE.md)."""
        self.robot.follow(joint_positions, openness)
        self.robot.step()

    def state(self) -> BulletArmState:
        """The robot's current state."""
        return self.robot.state()

    @property
    def _utensil_id(self) -> int:
        """The body of the task's utensil (told, or grasped; before a grasp of a utensil the
        robot is not told, the person's intended one)."""
        return self.world.utensils[self.task.utensil]

    def _holds(self, state: BulletArmState, name: str) -> bool:
        """The hand holds utensil `name`: the grasp helper, or fingers clamping it."""
        robot = self.robot
        gripping = robot.touching_groups(self.world.utensils[name]) & robot.closed_groups(0.5)
        return state.grasped == name or robot.clamps(gripping)

    def _observe(self, state: BulletArmState) -> TaskObservation:
        uid = self._utensil_id
        p, _ = pb.getBasePositionAndOrientation(uid, physicsClientId=self._c)
        task = self.task
        holding = None
        if not task.told and task.phase == Phase.PICK:
            holding = next((n for n in self.world.utensils if self._holds(state, n)), None)
        return TaskObservation(
            t_s=state.t_s,
            palm=state.palm,
            p_utensil_m=np.array(p, dtype=np.float64),
            held=self._holds(state, task.utensil),
            touching=any(c.other_body == uid for c in state.contacts),
            holding=holding,
        )

    def _grasp_pose(self, name: str) -> tuple[Array, Array]:
        p_u, R_u = self.utensil_pose(name)
        desc = self.config.description
        p_g, R_g = T_utensil_grasp(UTENSILS[name], desc.grasp_xyz_m, desc.grasp_depth_m)
        return p_u + R_u @ p_g, R_u @ R_g

    def grasp_pose(self, name: str | None = None) -> tuple[Array, Array]:
        """The palm pose that grasps utensil `name` (None: the task's) where it is now (p [m],
        R): the task's true pick goal until the utensil moves."""
        if name is not None and name not in UTENSILS:
            raise ConfigError(f"unknown utensil {name!r} (choose from {', '.join(UTENSIL_NAMES)})")
        return self._grasp_pose(name or self.task.utensil)

    def utensil_pose(self, name: str | None = None) -> tuple[Array, Array]:
        """True pose (COM position [m], R) of a utensil (default: the task's)."""
        uid = self.world.utensils[name] if name else self._utensil_id
        p, q = pb.getBasePositionAndOrientation(uid, physicsClientId=self._c)
        return np.array(p, dtype=np.float64), R_from_quat_xyzw(q)

    # ------------------------------------------------------------------ viewer export
    def geometry(self) -> SceneGeometry:
        """Every frame's visual geometry (computed once per reset)."""
        if self._geometry is None:
            self._geometry = self._build_geometry()
        return self._geometry

    def _build_geometry(self) -> SceneGeometry:
        robot, world, loaded = self.robot, self.world, self._loaded
        assert loaded is not None
        c = self._c
        frames: list[str] = []
        static: list[bool] = []
        visuals: list[VisualGeometry] = []
        link_frame: dict[int, str] = {}
        for name, idx in sorted(loaded.links.items(), key=lambda kv: kv[1]):
            link_frame[idx] = f"robot/{name}"
            frames.append(f"robot/{name}")
            static.append(idx == -1)
        kinds: dict[int, VisualKind] = {
            pb.GEOM_BOX: "box",
            pb.GEOM_SPHERE: "sphere",
            pb.GEOM_CYLINDER: "cylinder",
            pb.GEOM_CAPSULE: "capsule",
            pb.GEOM_MESH: "mesh",
            pb.GEOM_PLANE: "plane",
        }
        for vs in pb.getVisualShapeData(robot.body, physicsClientId=c):
            kind = kinds[vs[2]]
            dims = tuple(float(d) for d in vs[3])
            size: tuple[float, ...]
            if kind == "box":
                size = dims
            elif kind == "sphere":
                size = (dims[0],)
            elif kind in ("cylinder", "capsule"):
                size = (dims[1], dims[0])  # PyBullet reports (length, radius)
            else:
                size = ()
            mesh = vs[4].decode() if kind == "mesh" else None
            x, y, z, w = vs[6]
            r, g, b, a = vs[7]
            visuals.append(
                VisualGeometry(
                    link_frame[vs[1]],
                    kind,
                    size,
                    mesh,
                    (dims[0], dims[1], dims[2]) if kind == "mesh" else (1.0, 1.0, 1.0),
                    (float(r), float(g), float(b), float(a)),
                    (float(vs[5][0]), float(vs[5][1]), float(vs[5][2])),
                    (float(w), float(x), float(y), float(z)),
                )
            )
        body_frames = [(world.names[b], b) for b in (world.table, world.holder, world.bin)]
        body_frames += [(n, b) for n, b in world.utensils.items()]
        for name, b in body_frames:
            frames.append(name)
            static.append(b not in world.utensils.values())
            for part in world.parts[b]:
                size = part.size_m
                visuals.append(
                    VisualGeometry(
                        name,
                        part.kind,
                        tuple(float(s) for s in size),
                        None,
                        (1.0, 1.0, 1.0),
                        part.rgba,
                        part.p_body_part_m,
                        quat_wxyz_from_R(np.array(part.R_body_part)),
                    )
                )
        frames.append("floor")
        static.append(True)
        visuals.append(
            VisualGeometry(
                "floor",
                "plane",
                (),
                None,
                (1.0, 1.0, 1.0),
                (0.5, 0.5, 0.5, 1.0),
                (0.0, 0.0, 0.0),
                (1.0, 0.0, 0.0, 0.0),
            )
        )
        self._pose_links = [i for i in sorted(loaded.links.values()) if i >= 0]
        self._pose_bodies = [b for _, b in body_frames]
        fx, fy, fz = (float(v) for v in self.placement.point(np.array(SceneGeometry.focus_m)))
        return SceneGeometry(tuple(frames), tuple(static), tuple(visuals), (fx, fy, fz))

    def poses(self) -> ScenePoses:
        """World pose of every frame of `geometry()` now (wxyz quaternions)."""
        geo = self.geometry()
        c, body = self._c, self.robot.body
        n = len(geo.frames)
        P = np.zeros((n, 3))
        Q = np.zeros((n, 4))
        Q[:, 0] = 1.0
        # frame 0 is the robot base: the fixed-base URDF root frame is the base origin.
        states = pb.getLinkStates(
            body, self._pose_links, computeForwardKinematics=True, physicsClientId=c
        )
        k = 1
        for st in states:
            P[k] = st[4]
            x, y, z, w = st[5]
            Q[k] = (w, x, y, z)
            k += 1
        for b in self._pose_bodies:
            p, (x, y, z, w) = pb.getBasePositionAndOrientation(b, physicsClientId=c)
            P[k] = p
            Q[k] = (w, x, y, z)
            k += 1
        P[k] = self.placement.point(np.array([0.0, 0.0, FLOOR_Z_M]))
        return ScenePoses(self.robot.state_time_s, P, Q)
