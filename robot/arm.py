"""The arm + hand of a robot description under position control: pose and openness in,
achieved state out.

One control tick (`BulletArm.set_target` then `BulletArm.step`, `control_dt_s`: 1/30 s by default,
1/rate for a loop at another rate, `RobotConfig.for_period`):

    set_target(p, R, g):  p clamped into the workspace (box, then reach sphere about the
                          shoulder)  ->  IK (`kinematics.ArmChain.ik`: damped least
                          squares, joint limits, null-space pull to the rest posture,
                          warm-started from the last solution)  ->  position motors
                          finger joints: q = q_closed + g * (q_open - q_closed), per finger
                          (each joint's open and closed position from the description),
                          within the joint's URDF limits; each URDF `<mimic>` joint of a
                          finger joint (PyBullet ignores the tag): q = m q_master + o,
                          within its own limits
    step():               `substeps` physics steps of control_dt_s / substeps, then contacts
    state():              palm pose by forward kinematics of the simulated joints

Finger openness in the returned `HandState` is the commanded set-point, not the measured
one: a finger stopped by an object keeps squeezing as long as its command stays closed,
which is what a closed-loop integrator X_next = integrate(X_current, U, dt) needs (with the
measured value, a hand that stopped moving would command "as open as it is now" and let
go). The measured openness is `BulletArmState.openness_measured`.

Grasping is contact and friction. Four rules keep it stable in a rigid-body simulator:
    soft pads       the finger links touch like rubber fingertip pads: a spring-damper
                    contact (`pad_stiffness_n_per_m`, `pad_damping_n_s_per_m`) instead of a
                    rigid one. With rigid pads, PyBullet's iterative solver (10 iterations)
                    resolves only a fraction of a squeeze between a position-driven finger
                    and a 50-80 g utensil: pads sank 5-17 mm into the 24 mm grip, and the
                    grip force after closing was a median 4-6 N (down to 0.1 N) of the
                    motors' tens of newtons. A compliant contact is well posed for the
                    solver: median 13-15 N, at the same cost per tick.
    contact stall   a finger that touches a graspable body while closing stops there: its joint
                    angles are latched and its target then closes at most `squeeze_share` of its
                    travel past them. The motor squeezes with its full effort, but the pad cannot be
                    driven deep into the object (which makes objects wedge and pop out). It latches
                    only once the object is clamped (the thumb and an opposing finger both touch it)
                    and the command closes past the joints by more than `stall_lead_share` of the
                    travel: a finger that merely brushes the grip on the way (e.g. a proximal
                    phalanx grazing the grip's top edge, or an open finger pushed by the grip while
                    the hand approaches) pushes the object along and goes on closing. (Latching at
                    such a first touch, the finger stopped short of the grip and the grasp held with
                    next to no force.) The latch frees when the command opens past it.
    thumb effort    the thumb is as strong as the three fingers it opposes together (each
                    finger's effort is in the description).
    servo integral  a finger that holds a body (latched, or touching one that two groups clamp) has
                    a servo with integral action, as a real gripper's has: while one of its joints
                    (or a `<mimic>` of one) stands short of its target, the target sent to
                    PyBullet's motor is wound further in by the shortfall over
                    `finger_integral_time_s` each second (unwound while the joint stands past its
                    target), so the joint is driven to its target until the motor's force limit (the
                    description's) stops it; a finger whose target opens past its joints by more
                    than `stall_lead_share` of its travel lets go: its wind-up is dropped at once
                    (wound down gradually, the iiwa's hand held the ladle on while opening and flung
                    it off the table). Anti-windup: the wound target is at most the squeeze past the
                    target and never past the stall's limit, so a latched finger commanded closed
                    past that limit (the hand closing on a grip) has no room to wind and squeezes as
                    before; what the integral serves is a command that stops between the contact and
                    the limit. (Wound up to the limit, the hand's fingers drove 0.3 rad into the
                    spoon's grip and the UR5 dropped it in the goal-seeking run.) Without it
                    PyBullet's position motor (gain 0.3, 10 solver iterations) leaves a blocked
                    finger short of its target, pressing with a few percent of its effort: measured
                    on the xArm 6 (DS, seed 1, 2026-12-07), the drive 0.005-0.04 rad short of its
                    command with at most 0.03 of its 1.65 N m, its finger joints pushed 0.03-0.06
                    rad off the drive's angle (a rigid four-bar in the real gripper, separate motors
                    here), 0.1-0.3 N on each pad, and the spoon slid out as the arm lifted; the
                    Panda's jaws 1.7-3.3 N of their 70 N. A real gripper blocked short of its
                    position target presses up to its force limit: Franka's `grasp(width, speed,
                    force)` is force-controlled (libfranka), UFACTORY's gripper is a position servo
                    rated 30 N (no force setting: xarm_ros2 issue 42). A command that stops at the
                    contact still presses with next to nothing, as a real position servo commanded
                    to the object's own width would. Closed on the spoon's grip (goal-seeking,
                    noise-free) at openness 0.24, 0.016 rad past the pads' contact, and held 1 s:
                    the drive 0.007 rad short instead of 0.014 (its target wound 0.1 rad in), 2.6 N
                    per pad instead of 0.4 N, and the spoon lifts with the palm (it stayed;
                    tests/test_arms.py). The Panda at 0.26 is unchanged (3.1-3.3 N per jaw): its 2
                    mm squeeze puts the stall's limit at its command, so there is no room to wind.
"The thumb and an opposing finger" is, for any description, its `opposing` contact group
and another (the Panda: the left jaw and the right jaw).
`scripts/grasp_grid.py` measures it: it closes the hand at palm poses off the true grasp pose
and carries the utensil to the bin at the loop's limits. With rigid pads and a stall at the
first touch, 34/37 of the spoon's single-axis offsets (0.5-2 cm, 0.05-0.1 rad) and 35/40 of
its goal-noise offsets held; with the rules above 37/37 and 36/40 (the four misses are 2.2-2.6
cm off), spatula 34/37 -> 37/37, ladle 35/37 -> 36/37 (measured before the servo integral;
not re-measured with it).
An optional grasp helper (`grasp_helper=True`, off by default) adds a fixed constraint
between palm and object, created only when the thumb and at least one other finger whose
commands are closed (openness <= `helper_openness`) touch the same graspable body, and
removed as soon as the thumb or all the other fingers are commanded open; its strength is
`helper_max_force_n`. With the defaults the scripted run holds every utensil by friction
alone.

Steady state: before each physics step every robot link is held up by its own weight
(gravity compensation, the description's `[arm] gravity_compensation`, on unless it says
false, or `RobotConfig.gravity_compensation`: m g upwards at its centre of mass), as a real
arm's controller feeds its gravity torques forward. Without it the position motors (10 solver
iterations) leave the arm 0.1-1.3 mrad short of its target under gravity, and a goal-seeking
policy that steps from the achieved palm (X_next = X + K_r e dt) stops where its step equals
that sag: 3-8 mm short at K_r = 2 /s (docs/robot.md, `scripts/steady_state.py`); with it,
0.3 mm. An integral term would also remove the offset, but winds up against contact.

Quaternions cross this boundary as rotation matrices; PyBullet's xyzw stays inside.

Why one module: the control tick, the grasp rules above (soft pads, the stall latch, the servo
integral, the helper constraint) and the gravity compensation all act on one PyBullet body each
tick, through the same joint indices, finger tables and contact reads that `BulletArm` builds
from a description; split apart, each piece would reach into the others' state. Over a quarter
of the lines are these explanations; the arm's configuration (`RobotConfig`, `Workspace`) could
move out (~150 lines) and is kept beside the body it configures.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState, so3_log
from dsteleop.errors import ConfigError, InputError
from dsteleop.robot.bullet import pb
from dsteleop.robot.description import RobotDescription
from dsteleop.robot.kinematics import ArmChain
from dsteleop.robot.model import LoadedRobot
from dsteleop.robot.world import FINGER_FRICTION, R_from_quat_xyzw

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

CONTROL_DT_S = 1.0 / 30.0
#: The longest physics step `RobotConfig.for_rate` gives [s] (the default's: 1/30 s in 3).
MAX_PHYSICS_DT_S = CONTROL_DT_S / 3


@dataclass(frozen=True)
class Workspace:
    """Reachable region the palm target is clamped into, base frame [m].

    Attributes:
        lower_m: (x, y, z) lower corner of the box.
        upper_m: (x, y, z) upper corner of the box.
        shoulder_m: centre of the reach sphere (the iiwa's joint-2 axis).
        reach_m: radius of the reach sphere for the palm origin.
    """

    lower_m: tuple[float, float, float]
    upper_m: tuple[float, float, float]
    shoulder_m: tuple[float, float, float]
    reach_m: float

    @classmethod
    def of(cls, desc: RobotDescription) -> Workspace:
        """The workspace a robot description gives."""
        return cls(desc.workspace_min_m, desc.workspace_max_m, desc.shoulder_m, desc.reach_m)

    def clamp(self, p_m: Array) -> tuple[Array, bool]:
        """`p_m` moved into the box, then into the sphere; and whether it moved."""
        lo, hi, c = self.lower_m, self.upper_m, self.shoulder_m
        x = [min(max(float(p_m[k]), lo[k]), hi[k]) for k in range(3)]
        d = [x[k] - c[k] for k in range(3)]
        r = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if r > self.reach_m:
            x = [c[k] + d[k] * (self.reach_m / r) for k in range(3)]
        q = np.array(x)
        moved = any(abs(x[k] - float(p_m[k])) > 1e-9 for k in range(3))
        return q, moved


@dataclass(frozen=True)
class RobotConfig:
    """Control and physics settings (validated at construction).

    Attributes:
        substeps: physics steps per control tick (time step = control_dt_s / substeps).
        solver_iterations: PyBullet constraint-solver iterations per physics step.
        ik_iterations: maximum damped-least-squares iterations per tick.
        ik_tol_m: IK stops when the position error is below this [m] ...
        ik_tol_rad: ... and the orientation error below this [rad].
        ik_damping_m: lambda of the damped least squares (regularises singularities) [m].
        unreachable_tol_m: position error of the IK solution above which the target is
            reported unreachable [m].
        unreachable_tol_rad: orientation error of the IK solution above which the target is
            reported unreachable [rad].
        arm_force_nm: motor effort limit of every arm joint [N m].
        finger_position_gain: PyBullet position gain of the finger motors.
        grasp_helper: enable the grasp helper constraint (module docstring; off: friction).
        helper_openness: a finger counts as closed when its commanded openness is <= this.
        helper_max_force_n: strength of the helper constraint [N].
        squeeze_share: a finger touching a graspable body closes at most this share of each
            joint's open-to-closed travel past the positions where it met it (module
            docstring: contact stall; the iiwa hand's joints travel 1 rad: 0.3 rad), unless
            its description gives its own (the Panda's gripper).
        finger_integral_time_s: the integral time of a latched finger's servo (module
            docstring: servo integral) [s]: the motor's target moves in by the joint's
            shortfall over this each second (a modelling constant, not the maker's: neither
            UFACTORY nor Franka publish their servo's; 0.1 s is three ticks at 30 Hz).
        stall_lead_share: a finger counts as closing (for the contact stall) when its
            command is this share of the travel more closed than its joints; a contact can
            push an open finger against its open stop by a hundredth of its travel, which
            is not closing.
        pad_stiffness_n_per_m: contact stiffness of the finger links (rubber pads, 1 mm
            per 10 N, about a robot fingertip's pad) [N/m] ...
        pad_damping_n_s_per_m: ... and their contact damping [N s/m] (about critical for a
            20-30 g phalanx on that spring: 2 sqrt(k m) = 28-35 N s/m).
        control_dt_s: simulated time of one control tick [s] (the loop's period).
        gravity_compensation: hold every robot link up against gravity (its weight at its
            centre of mass, each physics step), as a real arm's controller compensates its
            own weight (module docstring: steady state); None (the default): as the robot's
            description says (`[arm] gravity_compensation`, on unless it says false: the
            iiwa and the Panda say false, docs/robots.md).
        unreachable_stall_s: a target the IK keeps missing by more than a quarter of what
            each tick asks of it (and by more than `stall_min_m` / `stall_min_rad`) for this
            long is reported unreachable too [s]: the loop steps the palm a little towards
            its goal each tick, so each tick's target lies near the palm and its IK error
            stays below `unreachable_tol_m` even when the arm stands at its joint limits
            short of a goal out of reach (the palm stalled 6 cm short of the place pose with
            `unreachable` false).
        stall_min_m: the smallest position miss that counts as a stall [m] ...
        stall_min_rad: ... and orientation miss [rad].
    """

    substeps: int = 3
    solver_iterations: int = 10
    ik_iterations: int = 1
    ik_tol_m: float = 2e-5
    ik_tol_rad: float = 2e-4
    ik_damping_m: float = 0.02
    unreachable_tol_m: float = 0.01
    unreachable_tol_rad: float = math.radians(5.0)
    arm_force_nm: float = 300.0
    finger_position_gain: float = 0.3
    grasp_helper: bool = False
    helper_openness: float = 0.5
    helper_max_force_n: float = 40.0
    squeeze_share: float = 0.3
    finger_integral_time_s: float = 0.1
    stall_lead_share: float = 0.02
    pad_stiffness_n_per_m: float = 1.0e4
    pad_damping_n_s_per_m: float = 30.0
    control_dt_s: float = CONTROL_DT_S
    gravity_compensation: bool | None = None
    unreachable_stall_s: float = 0.5
    stall_min_m: float = 5e-4
    stall_min_rad: float = 5e-3

    @classmethod
    def for_period(cls, control_dt_s: float, **kw: Any) -> RobotConfig:
        """The config of a loop whose period is `control_dt_s` [s]: one control tick is that
        much simulated time, in as many physics steps as keep each at most
        `MAX_PHYSICS_DT_S` (3 at 30 Hz, as the controllers were tuned; 9 at 10 Hz, 1 at
        120 Hz)."""
        dt = float(control_dt_s)
        if not (math.isfinite(dt) and dt > 0):
            raise ConfigError(f"robot config: control_dt_s must be > 0, got {control_dt_s!r}")
        substeps = max(1, math.ceil(dt / MAX_PHYSICS_DT_S - 1e-9))
        return cls(control_dt_s=dt, substeps=substeps, **kw)

    def __post_init__(self) -> None:
        for name in ("substeps", "solver_iterations", "ik_iterations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ConfigError(f"robot config: {name} must be an integer >= 1, got {v!r}")
        for name in (
            "ik_tol_m",
            "ik_tol_rad",
            "ik_damping_m",
            "unreachable_tol_m",
            "unreachable_tol_rad",
            "arm_force_nm",
            "finger_position_gain",
            "helper_openness",
            "helper_max_force_n",
            "squeeze_share",
            "finger_integral_time_s",
            "stall_lead_share",
            "pad_stiffness_n_per_m",
            "pad_damping_n_s_per_m",
            "control_dt_s",
            "unreachable_stall_s",
            "stall_min_m",
            "stall_min_rad",
        ):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"robot config: {name} must be finite and > 0, got {v!r}")

    @property
    def physics_dt_s(self) -> float:
        """Physics time step [s]."""
        return self.control_dt_s / self.substeps


@dataclass(frozen=True)
class Contact:
    """One contact point between a robot link and another body.

    Attributes:
        robot_link: name of the robot link.
        other_body: body id of the other body.
        other_name: name of the other body ("table", "spoon", ...).
        p_base_contact_m: (3,) contact point on the robot link, base frame [m].
        normal_force_n: contact normal force [N].
    """

    robot_link: str
    other_body: int
    other_name: str
    p_base_contact_m: tuple[float, float, float]
    normal_force_n: float


@dataclass(frozen=True)
class BulletArmState:
    """What the robot achieved after a tick (never NaN).

    Attributes:
        palm: achieved palm pose (forward kinematics) in the base frame; openness is the
            commanded finger set-point (see module docstring), order `finger_names`.
        openness_measured: (F,) openness measured from the finger joints, in [0, 1].
        joint_positions_rad: every movable joint's position by name [rad, or m for a
            prismatic joint].
        contacts: contact points of robot links with other bodies.
        target_clamped: the last position target lay outside the workspace and was moved.
        unreachable: the IK solution misses the (clamped) target by more than the tolerance,
            or has fallen short of every tick's target for `RobotConfig.unreachable_stall_s`
            (the arm stalled short of a goal out of reach).
        ik_error_m: position error of the IK solution [m].
        ik_error_rad: orientation error of the IK solution [rad].
        grasped: name of the body held by the grasp helper, or None.
        t_s: simulated time since the last reset [s].
    """

    palm: HandState
    openness_measured: Array
    joint_positions_rad: Mapping[str, float]
    contacts: tuple[Contact, ...]
    target_clamped: bool
    unreachable: bool
    ik_error_m: float
    ik_error_rad: float
    grasped: str | None
    t_s: float


def _det3(R: Array) -> float:
    return float(
        R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1])
        - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
        + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0])
    )


def _as_vec(x: object, n: int, name: str) -> Array:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (n,):
        raise InputError(f"{name} must have shape ({n},), got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{name} must be finite, got {a.tolist()}")
    return a


class BulletArm:
    """The arm + hand in a PyBullet client; see the module docstring for one tick.

    Args:
        client: PyBullet physics client id (DIRECT mode).
        loaded: the loaded robot body with its joint and link tables.
        chain: the arm's kinematic chain (base -> palm), read from the same URDF.
        config: control and physics settings.
        desc: the robot's description (arm joints, palm frame, fingers, rest posture,
            workspace).
        body_names: names of other bodies, for contact reports.
        graspable: bodies the grasp helper may hold.
    """

    def __init__(
        self,
        client: int,
        loaded: LoadedRobot,
        chain: ArmChain,
        config: RobotConfig,
        desc: RobotDescription,
        body_names: Mapping[int, str] | None = None,
        graspable: tuple[int, ...] = (),
    ) -> None:
        self._c = client
        self.desc = desc
        self.workspace = Workspace.of(desc)
        self._graspable = frozenset(graspable)
        self._state_cache: BulletArmState | None = None
        self._held: int | None = None
        self._helper_cid: int | None = None
        self._contacts: tuple[Contact, ...] = ()
        self._r = loaded
        self.config = config
        self._body = loaded.body
        self._names = dict(body_names or {})
        self._link_names = {i: n for n, i in loaded.links.items()}
        self._palm = loaded.links[desc.palm_frame_link]
        self._arm = [loaded.joints[n] for n in desc.arm_joints]
        fjoints = desc.finger_joints
        self._finger_names = desc.finger_names
        #: finger index of each finger joint; each finger's joint positions in that order
        self._joint_finger = np.array(
            [k for k, f in enumerate(desc.fingers) for _ in f.joints], dtype=np.intp
        )
        self._finger_slices = [
            np.flatnonzero(self._joint_finger == k) for k in range(len(desc.fingers))
        ]
        # Mimic joints (`description.MimicJoint`): driven at m q_master + o from their master
        # finger joint's command, within their own limits; their links take its group.
        finger_at = {j.name: k for k, j in enumerate(fjoints)}
        mimics = desc.mimic_joints
        self._mimic_idx = [loaded.joints[m.name].index for m in mimics]
        self._mimic_master = np.array([finger_at[m.master] for m in mimics], dtype=np.intp)
        self._mimic_m = np.array([m.multiplier for m in mimics], dtype=np.float64)
        self._mimic_o = np.array([m.offset for m in mimics], dtype=np.float64)
        self._mimic_lo = np.array([-np.inf if m.lower is None else m.lower for m in mimics])
        self._mimic_hi = np.array([np.inf if m.upper is None else m.upper for m in mimics])
        limits = {n: (lo, hi) for n, lo, hi in desc.finger_limits}
        self._finger_lo = np.array([limits.get(j.name, (-np.inf, np.inf))[0] for j in fjoints])
        self._finger_hi = np.array([limits.get(j.name, (np.inf, np.inf))[1] for j in fjoints])
        #: contact group of each finger link (by link name), and the fingers of each group
        link_finger: dict[str, tuple[str, str]] = {}  # link -> (group, finger)
        for k, j in enumerate(fjoints):
            f = desc.fingers[int(self._joint_finger[k])].name
            link_finger[self._link_names[loaded.joints[j.name].index]] = (j.group, f)
        for m, k in zip(mimics, self._mimic_master, strict=True):
            f = desc.fingers[int(self._joint_finger[k])].name
            link_finger[self._link_names[loaded.joints[m.name].index]] = (fjoints[k].group, f)
        for link, group in desc.link_groups:  # a pad's own group; its finger: up the tree
            li, owner = loaded.links[link], ""
            while li >= 0 and not owner:
                owner = link_finger.get(self._link_names[li], ("", ""))[1]
                li = int(pb.getJointInfo(loaded.body, li, physicsClientId=client)[16])
            link_finger[link] = (group, owner)
        self.link_group: dict[str, str] = {ln: g for ln, (g, _) in link_finger.items()}
        self._group_fingers: dict[str, set[str]] = {}
        for g, f in link_finger.values():
            self._group_fingers.setdefault(g, set())
            if f:
                self._group_fingers[g].add(f)
        movable = sorted(loaded.joints.values(), key=lambda j: j.index)
        self._chain = chain
        self._q_rest = np.array(desc.rest_posture_rad)
        self._arm_idx = [j.index for j in self._arm]
        self._arm_lo = np.array([j.lower_rad for j in self._arm])
        self._arm_hi = np.array([j.upper_rad for j in self._arm])
        self._finger_idx = [loaded.joints[j.name].index for j in fjoints]
        self._arm_forces = [config.arm_force_nm] * len(self._arm)
        self._arm_gains = [desc.arm_position_gain] * len(self._arm)
        self._finger_gains = [config.finger_position_gain] * len(self._finger_idx)
        self._finger_forces = [f.force for f in desc.fingers for _ in f.joints]
        self._mimic_forces = [self._finger_forces[int(k)] for k in self._mimic_master]
        self._mimic_gains = [config.finger_position_gain] * len(self._mimic_idx)
        self._all_idx = [j.index for j in movable]
        self._q_open = np.array([j.open for j in fjoints])
        self._q_closed = np.array([j.closed for j in fjoints])
        self._travel = np.abs(self._q_open - self._q_closed)
        #: per finger joint: how far it may close past where it met a held body [rad or m]
        self._squeeze = self._travel * np.array(
            [
                config.squeeze_share if f.squeeze_share is None else f.squeeze_share
                for f in desc.fingers
                for _ in f.joints
            ]
        )
        self._sense = np.sign(self._q_closed - self._q_open)  # +1 where closing raises q
        self._stall_q = np.full(len(fjoints), np.nan)  # per finger joint, NaN = free
        #: servo integral (module docstring): how far each finger joint's and each mimic
        #: joint's motor target is wound past its target, in the closing sense [rad or m]
        self._wind_f = np.zeros(len(fjoints))
        self._wind_m = np.zeros(len(self._mimic_idx))
        self._mimic_sense = self._sense[self._mimic_master] * np.sign(self._mimic_m)
        self._pressing = np.zeros(len(fjoints), dtype=bool)
        self._t_s = 0.0
        self._openness_cmd = np.ones(len(desc.fingers))
        self._q_arm_cmd = self._q_rest.copy()
        self._clamped = False
        self._unreachable = False
        self._stall_ticks = 0
        self._stalled = False
        self._stall_limit = max(1, round(config.unreachable_stall_s / config.control_dt_s))
        self._stall_said = False
        self._ik_err_m = 0.0
        self._ik_err_rad = 0.0
        #: gravity compensation: each moving link and the force that holds it up [N]
        self._gc_links: list[int] = []
        self._gc_forces: list[tuple[float, float, float]] = []
        gc = config.gravity_compensation
        if desc.gravity_compensation if gc is None else gc:
            params = pb.getPhysicsEngineParameters(physicsClientId=client)
            gx, gy, gz = (float(params[f"gravityAcceleration{a}"]) for a in "XYZ")
            for li in sorted(set(loaded.links.values()) - {-1}):
                mass = float(pb.getDynamicsInfo(loaded.body, li, physicsClientId=client)[0])
                if mass > 0.0:
                    self._gc_links.append(li)
                    self._gc_forces.append((-mass * gx, -mass * gy, -mass * gz))
        pb.setPhysicsEngineParameter(
            fixedTimeStep=config.physics_dt_s,
            numSubSteps=0,
            numSolverIterations=config.solver_iterations,
            physicsClientId=client,
        )
        for info in loaded.joints.values():
            # no extra damping: the position motors alone shape the response (the iiwa URDF's
            # 0.5 N m s/rad joint damping would fight the motors at every tick)
            pb.changeDynamics(
                self._body,
                info.index,
                linearDamping=0.0,
                angularDamping=0.0,
                jointDamping=0.0 if info.name in desc.arm_joints else 0.01,
                physicsClientId=client,
            )
        pads = sorted({loaded.links[ln] for ln in self.link_group})
        for li in pads:  # every finger link: the finger joints', the mimics', link_groups'
            pb.changeDynamics(
                self._body,
                li,
                lateralFriction=FINGER_FRICTION,
                spinningFriction=desc.spinning_friction,
                frictionAnchor=True,
                contactStiffness=config.pad_stiffness_n_per_m,
                contactDamping=config.pad_damping_n_s_per_m,
                physicsClientId=client,
            )

    # ------------------------------------------------------------------ properties
    @property
    def body(self) -> int:
        """PyBullet body id of the robot."""
        return self._body

    @property
    def link_names(self) -> Mapping[int, str]:
        """Link index -> link name (base is -1)."""
        return self._link_names

    @property
    def finger_names(self) -> tuple[str, ...]:
        """Finger names in the order of the openness vector."""
        return self._finger_names

    def finger_joint_limits_rad(self) -> dict[str, tuple[float, float]]:
        """(open, closed) position of every finger joint, by joint name [rad or m]."""
        return {j.name: (j.open, j.closed) for j in self.desc.finger_joints}

    def clamps(self, groups: set[str]) -> bool:
        """`groups` touching (or closing on) a body clamp it: the opposing group and another."""
        return self.desc.opposing in groups and len(groups) > 1

    # ------------------------------------------------------------------ control
    def reset_posture(self, p_m: Array, R: Array, openness: Array) -> None:
        """Teleport the joints to an IK solution of a palm pose (no dynamics), motors holding.

        Raises:
            InputError: if the pose is not reachable.
        """
        p_m = _as_vec(p_m, 3, "position")
        g = np.clip(_as_vec(openness, len(self._finger_names), "openness"), 0.0, 1.0)
        res = self._chain.ik(
            p_m, np.asarray(R, dtype=np.float64), self._q_rest, self._q_rest, iterations=100
        )
        if res.error_m > self.config.unreachable_tol_m:
            raise InputError(f"reset pose {p_m.tolist()} is not reachable")
        self._q_arm_cmd = res.q_rad
        for k, j in enumerate(self._arm):
            pb.resetJointState(self._body, j.index, float(res.q_rad[k]), physicsClientId=self._c)
        q_f = self._finger_q(g)
        for k, idx in enumerate(self._finger_idx):
            pb.resetJointState(self._body, idx, float(q_f[k]), physicsClientId=self._c)
        for k, idx in enumerate(self._mimic_idx):
            q_m = float(self._mimic_q(q_f)[k])
            pb.resetJointState(self._body, idx, q_m, physicsClientId=self._c)
        self._t_s = 0.0
        self._state_cache = None
        self.release()
        self._stall_q[:] = np.nan
        self._wind_f[:] = 0.0
        self._wind_m[:] = 0.0
        self._pressing[:] = False
        self._stall_ticks = 0
        self._stalled = False
        self._stall_said = False
        self.set_target(p_m, R, g)

    def set_target(self, position_m: Array, rotation: Array, openness: Array) -> None:
        """Command a palm pose and finger openness; applied by the next `step()`.

        Args:
            position_m: (3,) palm position in the base frame [m]; clamped to the workspace.
            rotation: (3, 3) palm orientation R_base_palm.
            openness: (F,) finger openness in [0, 1], order `finger_names` (clipped).

        Raises:
            InputError: on wrong shapes or non-finite values.
        """
        self._state_cache = None
        p = _as_vec(position_m, 3, "position")
        R = np.asarray(rotation, dtype=np.float64)
        if R.shape != (3, 3) or not np.isfinite(R).all():
            raise InputError(f"rotation must be a finite 3x3 matrix, got shape {R.shape}")
        g = np.clip(_as_vec(openness, len(self._finger_names), "openness"), 0.0, 1.0)
        # R^T R = I and det R = +1 (the triple product, not LAPACK: see kinematics._solve_spd)
        if float(np.abs(R.T @ R - np.eye(3)).max()) > 1e-3 or _det3(R) < 0.0:
            raise InputError("rotation must be a proper rotation matrix (R^T R = I, det +1)")
        p_c, self._clamped = self.workspace.clamp(p)
        q = self._solve_ik(p_c, R, self.config.ik_iterations)
        if np.isfinite(q).all():
            self._q_arm_cmd = np.clip(q, self._arm_lo, self._arm_hi)
        self._openness_cmd = g
        pb.setJointMotorControlArray(
            self._body,
            self._arm_idx,
            pb.POSITION_CONTROL,
            targetPositions=self._q_arm_cmd.tolist(),
            forces=self._arm_forces,
            positionGains=self._arm_gains,
            physicsClientId=self._c,
        )
        self._apply_fingers()

    def _finger_targets(self) -> Array:
        """The finger joints' targets: the command, capped by the contact stall."""
        q_f = self._finger_q(self._openness_cmd)
        # Contact stall: a finger stops where it met the object (plus a squeeze) instead of
        # driving its pad into it; NaN entries (free fingers) leave the command as it is.
        limit = self._stall_q + self._sense * self._squeeze
        return np.where(self._sense * (q_f - limit) > 0.0, limit, q_f)

    def _apply_fingers(self) -> None:
        self._command_fingers(self._finger_targets(), self._wind_f, self._wind_m)

    def _command_fingers(
        self, q_f: Array, wind_f: Array | None = None, wind_m: Array | None = None
    ) -> None:
        """Position targets for the finger joints (within their URDF limits) and, from
        them, for their mimic joints; each motor's wound past its target by `wind_f` /
        `wind_m` in the closing sense (module docstring: servo integral)."""
        q_m = self._mimic_q(np.clip(q_f, self._finger_lo, self._finger_hi))
        if wind_m is not None:
            q_m = np.clip(q_m + self._mimic_sense * wind_m, self._mimic_lo, self._mimic_hi)
        if wind_f is not None:
            q_f = q_f + self._sense * wind_f
        q_f = np.clip(q_f, self._finger_lo, self._finger_hi)
        pb.setJointMotorControlArray(
            self._body,
            self._finger_idx,
            pb.POSITION_CONTROL,
            targetPositions=q_f.tolist(),
            forces=self._finger_forces,
            positionGains=self._finger_gains,
            physicsClientId=self._c,
        )
        if self._mimic_idx:
            pb.setJointMotorControlArray(
                self._body,
                self._mimic_idx,
                pb.POSITION_CONTROL,
                targetPositions=q_m.tolist(),
                forces=self._mimic_forces,
                positionGains=self._mimic_gains,
                physicsClientId=self._c,
            )

    def _mimic_q(self, q_f: Array) -> Array:
        """Each mimic joint's position for finger joint positions q_f: m q_master + o,
        within its limits."""
        q = self._mimic_m * q_f[self._mimic_master] + self._mimic_o
        return np.asarray(np.clip(q, self._mimic_lo, self._mimic_hi))

    def _finger_q(self, g: Array) -> Array:
        per_joint = g[self._joint_finger]
        return self._q_closed + per_joint * (self._q_open - self._q_closed)

    def _solve_ik(self, p_m: Array, R: Array, iterations: int) -> Array:
        p_from, R_from = self._chain.fk(self._q_arm_cmd)
        asked_m = float(np.linalg.norm(p_m - p_from))
        asked_rad = float(np.linalg.norm(so3_log(R @ R_from.T)))
        res = self._chain.ik(
            p_m,
            R,
            self._q_arm_cmd,
            self._q_rest,
            iterations=iterations,
            tol_m=self.config.ik_tol_m,
            tol_rad=self.config.ik_tol_rad,
            damping=self.config.ik_damping_m,
        )
        self._ik_err_m, self._ik_err_rad = res.error_m, res.error_rad
        c = self.config
        # A stall: the step met less than three quarters of what the tick asked. A leaky
        # count (+1 a stalled tick, -2 another) with hysteresis: set at the limit, cleared
        # at 0, so the odd tick the palm jitters forward does not clear it.
        stalled = (res.error_m > c.stall_min_m and res.error_m > 0.25 * asked_m) or (
            res.error_rad > c.stall_min_rad and res.error_rad > 0.25 * asked_rad
        )
        n = self._stall_ticks + 1 if stalled else max(0, self._stall_ticks - 2)
        self._stall_ticks = min(n, self._stall_limit)
        if self._stall_ticks >= self._stall_limit:
            self._stalled = True
        elif self._stall_ticks == 0:
            self._stalled = False
        self._unreachable = (
            res.error_m > c.unreachable_tol_m
            or res.error_rad > c.unreachable_tol_rad
            or self._stalled
        )
        if self._stalled and not self._stall_said:
            self._stall_said = True  # once per reset: the first stall, with where
            log.warning(
                "the palm stalls short of its target (%.3f, %.3f, %.3f) m: out of reach, the "
                "arm misses it by %.1f mm / %.1f deg a tick (dsteleop robot check tells "
                "whether the task is in reach)",
                *p_m, 1e3 * res.error_m, math.degrees(res.error_rad),
            )  # fmt: skip
        return res.q_rad

    def follow(self, joint_positions: Mapping[str, float], openness: Array) -> None:
        """Command every arm and finger joint to a measured position (by name; joints not
        given hold), and take `openness` as the finger command: this robot is the twin of
        one outside this world (`env.KitchenEnv.follow`); applied by the next `step()`."""
        self._state_cache = None
        g = np.clip(_as_vec(openness, len(self._finger_names), "openness"), 0.0, 1.0)
        self._openness_cmd = g
        for k, arm_joint in enumerate(self._arm):
            if arm_joint.name in joint_positions:
                self._q_arm_cmd[k] = float(joint_positions[arm_joint.name])
        q_f = self._finger_q(g)
        for k, name in enumerate(j.name for j in self.desc.finger_joints):
            if name in joint_positions:
                q_f[k] = float(joint_positions[name])
        pb.setJointMotorControlArray(
            self._body, self._arm_idx, pb.POSITION_CONTROL,
            targetPositions=self._q_arm_cmd.tolist(), forces=self._arm_forces,
            positionGains=self._arm_gains, physicsClientId=self._c,
        )  # fmt: skip
        self._command_fingers(q_f)

    def step(self) -> None:
        """Advance the physics by one control tick (`control_dt_s`) under the current targets."""
        self._state_cache = None
        for _ in range(self.config.substeps):
            self._compensate_gravity()
            pb.stepSimulation(physicsClientId=self._c)
        self._t_s += self.config.control_dt_s
        self._contacts = self._read_contacts()
        changed = self._update_stall()
        if self._update_wind() or changed:  # the fingers' motors told once, after both
            self._apply_fingers()
        if self.config.grasp_helper:
            self._update_helper()

    def _compensate_gravity(self) -> None:
        """Hold each of the robot's links up against gravity for the next physics step (its
        weight, upwards, at its centre of mass; PyBullet clears external forces after each
        step): module docstring, steady state. A held body's weight is not compensated."""
        if not self._gc_links:
            return
        states = pb.getLinkStates(
            self._body, self._gc_links, computeForwardKinematics=True, physicsClientId=self._c
        )
        for li, f, st in zip(self._gc_links, self._gc_forces, states, strict=True):
            pb.applyExternalForce(self._body, li, f, st[0], pb.WORLD_FRAME, physicsClientId=self._c)

    def touching_groups(self, body: int, others: str | None = None) -> set[str]:
        """The finger contact groups whose links touch `body` (as of the last step); with
        `others`, a link of no finger (the palm, the arm) counts as that group."""
        return {
            g
            for c in self._contacts
            if c.other_body == body and (g := self.link_group.get(c.robot_link, others)) is not None
        }

    def closed_groups(self, threshold: float) -> set[str]:
        """The contact groups of the fingers commanded at most `threshold` open."""
        closed = {
            f for f, g in zip(self._finger_names, self._openness_cmd, strict=True) if g <= threshold
        }
        return {grp for grp, fs in self._group_fingers.items() if fs & closed}

    def _update_stall(self) -> bool:
        """Latch each finger's joint positions when it touches a graspable body that the
        opposing group and another clamp, while closing; free it when its command opens past
        that point (module docstring: contact stall). Returns whether a latch changed (the
        fingers' motors then need their targets again)."""
        clamped: set[str] = set()  # fingers touching a body clamped between two groups
        for body in self._graspable:
            # a body between the opposing fingers and the palm (or the arm) is clamped too
            groups = self.touching_groups(body, others=" body")
            if self.clamps(groups):
                for grp in groups:
                    clamped |= self._group_fingers.get(grp, set())
        #: per finger joint: its finger touches a clamped body (module docstring: servo integral)
        self._pressing = np.isin(self._joint_finger, [self._finger_names.index(f) for f in clamped])
        q_cmd = self._finger_q(self._openness_cmd)
        changed = False
        states: list[tuple[float, ...]] | None = None
        for f, sl in zip(self._finger_names, self._finger_slices, strict=True):
            stalled = not np.isnan(self._stall_q[sl]).any()
            if stalled:
                # opened past the contact posture: the finger is free again
                if (self._sense[sl] * (q_cmd[sl] - self._stall_q[sl]) < 0.0).all():
                    self._stall_q[sl] = np.nan
                    changed = True
            elif f in clamped:
                if states is None:
                    states = pb.getJointStates(
                        self._body, self._finger_idx, physicsClientId=self._c
                    )
                q_now = np.array([states[i][0] for i in sl])
                lead = self._sense[sl] * (q_cmd[sl] - q_now)
                if (lead > self.config.stall_lead_share * self._travel[sl]).any():  # closing
                    self._stall_q[sl] = q_now
                    changed = True
        return changed

    def _update_wind(self) -> bool:
        """Wind each holding finger's motor targets in by its joints' shortfall, unwind any
        finger's past its target (module docstring: servo integral). Returns whether it did
        (the fingers' motors then need their targets again)."""
        latched = ~np.isnan(self._stall_q) | self._pressing
        if not latched.any() and not self._wind_f.any() and not self._wind_m.any():
            return False
        q_f = self._finger_targets()
        states = pb.getJointStates(
            self._body, self._finger_idx + self._mimic_idx, physicsClientId=self._c
        )
        q = np.array([s[0] for s in states])
        n = len(self._finger_idx)
        k = self.config.control_dt_s / self.config.finger_integral_time_s
        short_f = self._sense * (np.clip(q_f, self._finger_lo, self._finger_hi) - q[:n])
        # a finger that holds nothing keeps its wind-up but only unwinds (a contact that
        # flickers for a tick does not drop the press)
        short_f = np.where(latched, short_f, np.minimum(short_f, 0.0))
        # anti-windup: at most the squeeze past the target, and never past the stall's limit
        # (a latched finger whose command closes past that limit has no room to wind)
        room = self._sense * (self._stall_q + self._sense * self._squeeze - q_f)
        room = np.clip(np.where(np.isnan(room), self._squeeze, room), 0.0, self._squeeze)
        # a finger whose target opens past its joints by more than the stall's lead lets
        # go: its wind-up is dropped at once (winding down, it held the body a while longer)
        room = np.where(short_f < -self.config.stall_lead_share * self._travel, 0.0, room)
        self._wind_f = np.clip(self._wind_f + k * short_f, 0.0, room)
        if self._mimic_idx:
            q_m = self._mimic_q(np.clip(q_f, self._finger_lo, self._finger_hi))
            short_m = self._mimic_sense * (q_m - q[n:])
            short_m = np.where(latched[self._mimic_master], short_m, np.minimum(short_m, 0.0))
            room_m = np.abs(self._mimic_m) * room[self._mimic_master]
            self._wind_m = np.clip(self._wind_m + k * short_m, 0.0, room_m)
        return True

    def _update_helper(self) -> None:
        closed = self.closed_groups(self.config.helper_openness)
        if self._helper_cid is not None:
            if not self.clamps(closed):
                self.release()
            return
        if not self.clamps(closed):
            return
        for body in sorted(self._graspable):
            if self.clamps(self.touching_groups(body) & closed):
                self._engage(body)
                return

    def _engage(self, body: int) -> None:
        """Fix `body` to the palm at its current relative pose (both COM frames)."""
        ls = pb.getLinkState(self._body, self._palm, physicsClientId=self._c)
        p_wp, q_wp = ls[0], ls[1]
        p_wb, q_wb = pb.getBasePositionAndOrientation(body, physicsClientId=self._c)
        inv_p, inv_q = pb.invertTransform(p_wp, q_wp)
        p_pb, q_pb = pb.multiplyTransforms(inv_p, inv_q, p_wb, q_wb)
        self._helper_cid = pb.createConstraint(
            self._body,
            self._palm,
            body,
            -1,
            pb.JOINT_FIXED,
            (0.0, 0.0, 0.0),
            parentFramePosition=p_pb,
            childFramePosition=(0.0, 0.0, 0.0),
            parentFrameOrientation=q_pb,
            childFrameOrientation=(0.0, 0.0, 0.0, 1.0),
            physicsClientId=self._c,
        )
        pb.changeConstraint(
            self._helper_cid, maxForce=self.config.helper_max_force_n, physicsClientId=self._c
        )
        self._held = body
        log.debug("grasp helper engaged on body %d", body)

    def release(self) -> None:
        """Remove the grasp helper constraint, if engaged."""
        if self._helper_cid is not None:
            pb.removeConstraint(self._helper_cid, physicsClientId=self._c)
            log.debug("grasp helper released body %s", self._held)
        self._helper_cid = None
        self._held = None
        self._state_cache = None

    def reset_clock(self) -> None:
        """Restart the simulated time at 0 (after the scene settled)."""
        self._t_s = 0.0
        self._state_cache = None

    @property
    def state_time_s(self) -> float:
        """Simulated time since the last reset [s]."""
        return self._t_s

    # ------------------------------------------------------------------ read-back
    def palm_pose(self) -> tuple[Array, Array]:
        """Achieved palm pose (p [m], R_base_palm) by forward kinematics."""
        ls = pb.getLinkState(
            self._body, self._palm, computeForwardKinematics=True, physicsClientId=self._c
        )
        return np.array(ls[4], dtype=np.float64), R_from_quat_xyzw(ls[5])

    def openness_measured(self, q_by_index: Mapping[int, float] | None = None) -> Array:
        """Openness of each finger from its joint positions, mean over its joints, in [0, 1]."""
        if q_by_index is None:
            states = pb.getJointStates(self._body, self._finger_idx, physicsClientId=self._c)
            q = np.array([s[0] for s in states])
        else:
            q = np.array([q_by_index[i] for i in self._finger_idx])
        g = (q - self._q_closed) / (self._q_open - self._q_closed)
        per_finger = np.bincount(self._joint_finger, g) / np.bincount(self._joint_finger)
        return np.asarray(np.clip(per_finger, 0.0, 1.0))  # mean over each finger's joints

    def contacts(self) -> tuple[Contact, ...]:
        """Contact points of the robot's links with other bodies, as of the last step."""
        return self._contacts

    def _read_contacts(self) -> tuple[Contact, ...]:
        out = []
        for c in pb.getContactPoints(bodyA=self._body, physicsClientId=self._c):
            if c[2] == self._body:
                continue
            out.append(
                Contact(
                    self._link_names.get(c[3], str(c[3])),
                    int(c[2]),
                    self._names.get(int(c[2]), str(c[2])),
                    (float(c[5][0]), float(c[5][1]), float(c[5][2])),
                    float(c[9]),
                )
            )
        return tuple(out)

    def state(self) -> BulletArmState:
        """The achieved state after the last tick (see `BulletArmState`); cached until the next
        `set_target`, `step` or reset."""
        if self._state_cache is None:
            self._state_cache = self._read_state()
        return self._state_cache

    def _read_state(self) -> BulletArmState:
        p, R = self.palm_pose()
        states = pb.getJointStates(self._body, self._all_idx, physicsClientId=self._c)
        q_by_index = {i: float(s[0]) for i, s in zip(self._all_idx, states, strict=True)}
        joints = {n: q_by_index[j.index] for n, j in self._r.joints.items()}
        if not (np.isfinite(p).all() and np.isfinite(R).all()):  # pragma: no cover - guard
            raise InputError("simulation diverged: palm pose is not finite")
        return BulletArmState(
            palm=HandState(p, R, self._openness_cmd.copy()),
            openness_measured=self.openness_measured(q_by_index),
            joint_positions_rad=MappingProxyType(joints),
            contacts=self._contacts,
            target_clamped=self._clamped,
            unreachable=self._unreachable,
            ik_error_m=self._ik_err_m,
            ik_error_rad=self._ik_err_rad,
            grasped=None if self._held is None else self._names.get(self._held, str(self._held)),
            t_s=self._t_s,
        )
