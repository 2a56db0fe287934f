"""`dsteleop robot check`: does a robot description do the kitchen task? Each check, measured.

    placement   where the task's scene stands in the base frame (`robot.placement`: the
                description's `[task]`, or computed, `robot.reach`)
    reach       each task pose (each utensil's grasp pose, the place pose, the home) at its
                grasp orientation: the arm's IK error [mm, deg] and whether it lies in the
                workspace (`robot.reach.reach_all`)
    steady      the palm commanded to a still pose in free air (above the middle pocket, and
                the place pose), held `STEADY_S`: its distance from the pose after settling
                (the mean over the last 0.5 s) [mm], both as the arm's own tracking (the pose
                commanded every tick) and under the goal-seeking policy stepping from the
                achieved palm (`robot.scripted`, as the loop does at alpha = 1); the
                commanded pose within `STEADY_TOL_M` passes, and the goal-seeking one too
                when the arm holds its own weight (gravity compensation; without, the policy
                stops ~15 times the sag short, which is reported)
    grasp       per utensil, in the real PyBullet world: the goal-seeking policy with
                noise-free goals drives the palm to the grasp pose, closes the fingers there
                (the task's schedule) and lifts towards the place pose; it holds when the task
                saw the grasp (the fingers clamp it) and, `LIFT_S` later, the utensil is still
                held and `LIFT_M` higher than it stood
    derived     the arm's joints and their URDF limits, the finger joints' (and the mimic
                joints'), the home, the workspace box and reach sphere, and the arm's own
                reach (the farthest palm from the shoulder over `REACH_SAMPLES` random
                postures within the limits)

Every failed check is a problem: one line saying what and the fix. Pure measurement: nothing
is written.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import HandState
from dsteleop.robot.arm import BulletArmState, RobotConfig
from dsteleop.robot.description import RobotDescription
from dsteleop.robot.env import EnvConfig, KitchenEnv
from dsteleop.robot.placement import Placement
from dsteleop.robot.reach import (
    PLACE_POSITION_M,
    R_PALM_DOWN,
    PoseReach,
    arm_chain,
    home_pose,
    problems,
    reach_all,
    reach_pose,
    task_placement,
)
from dsteleop.robot.scripted import goal_seeking_step, noise_free
from dsteleop.robot.task import EventKind, Phase
from dsteleop.robot.world import UTENSIL_NAMES, pocket_center_m

Array = NDArray[np.float64]

#: How long a still pose is held [s], and the steady-state error that passes [m].
STEADY_S = 10.0
STEADY_TOL_M = 0.002
#: A grasp must come within this long [s] (noise-free goals: the scripted run takes 4-6 s).
GRASP_WITHIN_S = 30.0
#: After the grasp, the utensil must still be held this long later [s], this much higher [m].
LIFT_S = 1.5
LIFT_M = 0.03
#: Random postures for the arm's own reach.
REACH_SAMPLES = 4000


def steady_goals(placement: Placement) -> dict[str, Array]:
    """Still palm positions in free air (palm down), base frame: 0.44 m over the middle
    pocket (the fingers clear the utensils' tops) and the place pose."""
    return {
        "above the holder": placement.point(pocket_center_m(1) + np.array([0.0, -0.02, 0.44])),
        "place": placement.point(np.array(PLACE_POSITION_M)),
    }


@dataclass(frozen=True)
class Steady:
    """The palm's steady-state error at one still pose.

    Attributes:
        goal: the pose's name.
        command_m: the arm's own tracking: the pose commanded every tick [m].
        seek_m: under the goal-seeking policy from the achieved palm [m].
        contact: a robot link touched something (not in free air: not a fair measure).
        tried: the pose is reachable (else not measured: NaN).
        compensated: the arm held its own weight (gravity compensation).
    """

    goal: str
    command_m: float
    seek_m: float
    contact: bool
    tried: bool = True
    compensated: bool = True

    @property
    def ok(self) -> bool:
        """The commanded pose within `STEADY_TOL_M`, and the goal-seeking policy's too when
        the arm holds its own weight (without, the policy stops ~15 times the arm's sag
        short: reported, not failed)."""
        seek_ok = self.seek_m <= STEADY_TOL_M or not self.compensated
        return self.tried and self.command_m <= STEADY_TOL_M and seek_ok


@dataclass(frozen=True)
class Grasp:
    """The gripper closing on one utensil.

    Attributes:
        utensil: its name.
        tried: its grasp pose was reachable (else not tried).
        grasped_s: when the task saw the grasp [s], or None.
        held_after_lift: still held `LIFT_S` after the grasp.
        lift_m: how much higher its centre of mass was then than at the start [m].
        grip_force_n: the sum of the finger links' normal forces on it then [N].
    """

    utensil: str
    tried: bool
    grasped_s: float | None
    held_after_lift: bool
    lift_m: float
    grip_force_n: float

    @property
    def ok(self) -> bool:
        return self.tried and self.held_after_lift and self.lift_m >= LIFT_M


@dataclass
class Report:
    """What `check` found (module docstring)."""

    desc: RobotDescription
    placement: Placement
    reaches: list[PoseReach]
    steady: list[Steady]
    grasps: list[Grasp]
    derived: dict[str, Any]
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready values (mm and deg where a person reads them)."""
        return {
            "robot": self.desc.name,
            "file": str(self.desc.path),
            "ok": self.ok,
            "placement": self.placement.to_dict(),
            "reach": [
                {
                    "pose": r.name,
                    "position_m": [round(float(v), 4) for v in r.position_m],
                    "error_mm": round(1e3 * r.error_m, 2),
                    "error_deg": round(math.degrees(r.error_rad), 2),
                    "outside": r.outside or None,
                    "reachable": r.reachable,
                }
                for r in self.reaches
            ],
            "steady_state": [
                {
                    "goal": s.goal,
                    "command_mm": round(1e3 * s.command_m, 2) if s.tried else None,
                    "seek_mm": round(1e3 * s.seek_m, 2) if s.tried else None,
                    "contact": s.contact,
                    "gravity_compensation": s.compensated,
                    "ok": s.ok,
                }
                for s in self.steady
            ],
            "grasp": [
                {
                    "utensil": g.utensil,
                    "tried": g.tried,
                    "grasped_s": None if g.grasped_s is None else round(g.grasped_s, 2),
                    "held_after_lift": g.held_after_lift,
                    "lift_mm": round(1e3 * g.lift_m, 1),
                    "grip_force_n": round(g.grip_force_n, 1),
                    "ok": g.ok,
                }
                for g in self.grasps
            ],
            "derived": self.derived,
            "problems": list(self.problems),
        }

    def lines(self) -> list[str]:
        """The report for a person, one fact a line."""
        d = self.desc
        out = [f"robot {d.name}: {d.title} ({d.path})", f"placement: {self.placement.describe()}"]
        out.append("reach (IK at each task pose's grasp orientation):")
        for r in self.reaches:
            p = ", ".join(f"{v:.3f}" for v in r.position_m)
            flag = "ok" if r.reachable else "UNREACHABLE"
            extra = f" ({r.outside})" if r.outside else ""
            out.append(
                f"  {r.name:<14} ({p}) m  error {1e3 * r.error_m:7.2f} mm "
                f"{math.degrees(r.error_rad):6.2f} deg  {flag}{extra}"
            )
        out.append(f"steady state (still pose held {STEADY_S:g} s; pass <= 2 mm):")
        for s in self.steady:
            if not s.tried:
                out.append(f"  {s.goal:<16} not measured: out of reach  FAIL")
                continue
            flag = "ok" if s.ok else "FAIL"
            touch = " (touching something)" if s.contact else ""
            gc = "" if s.compensated else " (no gravity compensation: goal-seeking reported)"
            out.append(
                f"  {s.goal:<16} commanded {1e3 * s.command_m:6.2f} mm, goal-seeking "
                f"{1e3 * s.seek_m:6.2f} mm  {flag}{touch}{gc}"
            )
        out.append(f"grasp (close at the grasp pose, lift for {LIFT_S:g} s):")
        for g in self.grasps:
            if not g.tried:
                out.append(f"  {g.utensil:<8} not tried: its grasp pose is out of reach")
                continue
            when = "never" if g.grasped_s is None else f"at {g.grasped_s:.1f} s"
            flag = "ok" if g.ok else "FAIL"
            out.append(
                f"  {g.utensil:<8} grasped {when}, held after the lift: "
                f"{'yes' if g.held_after_lift else 'no'}, lifted {1e3 * g.lift_m:.0f} mm, "
                f"grip {g.grip_force_n:.1f} N  {flag}"
            )
        out.append("derived:")
        for k, v in self.derived.items():
            out.append(f"  {k}: {_fmt(v)}")
        if self.problems:
            out.append(f"problems ({len(self.problems)}):")
            out += [f"  {p}" for p in self.problems]
        else:
            out.append("no problems: every check passes")
        return out


def _fmt(v: Any) -> str:
    if isinstance(v, dict):
        return "; ".join(f"{k} {_fmt(x)}" for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def derived_values(desc: RobotDescription) -> dict[str, Any]:
    """Joint limits, home, workspace and reach (module docstring)."""
    chain = arm_chain(desc)
    rng = np.random.default_rng(0)
    lo = np.where(np.isfinite(chain.lower_rad), chain.lower_rad, -math.pi)
    hi = np.where(np.isfinite(chain.upper_rad), chain.upper_rad, math.pi)
    shoulder = np.array(desc.shoulder_m)
    far = 0.0
    for _ in range(REACH_SAMPLES):
        p, _R = chain.fk(rng.uniform(lo, hi))
        far = max(far, float(np.linalg.norm(p - shoulder)))
    p_home, R_home = home_pose(desc)
    return {
        "arm_joints_rad": {
            n: [round(float(a), 4), round(float(b), 4)]
            for n, a, b in zip(chain.names, chain.lower_rad, chain.upper_rad, strict=True)
        },
        "finger_joints": {n: [round(a, 4), round(b, 4)] for n, a, b in desc.finger_limits},
        "mimic_joints": {
            m.name: f"{m.multiplier:g} * {m.master} + {m.offset:g}" for m in desc.mimic_joints
        },
        "home_m": [round(float(v), 4) for v in p_home],
        "home_rotvec_rad": [round(float(v), 4) for v in desc.home_rotvec_rad],
        "home_palm_z_in_base": [round(float(v), 3) for v in R_home[:, 2]],
        "workspace_box_m": [list(desc.workspace_min_m), list(desc.workspace_max_m)],
        "shoulder_m": list(desc.shoulder_m),
        "reach_m (limits)": desc.reach_m,
        "arm_reach_m (sampled)": round(far, 3),
    }


def hold_still(
    env: KitchenEnv,
    goal: HandState,
    how: str,
    on_settled: Callable[[BulletArmState], None] | None = None,
    seconds: float = STEADY_S,
) -> list[float]:
    """Reset `env` and drive its palm to the still `goal` for `seconds`: `how` "command"
    sends the goal itself every tick (the arm's own tracking), "seek" the goal-seeking
    policy's step from the achieved palm (as the loop does at alpha = 1). Returns the palm's
    distance to the goal [m] at each tick of the last 0.5 s (the settled tail); `on_settled`
    sees each of those ticks' state too."""
    X = env.reset("spoon").palm
    ticks = round(seconds / env.dt_s)
    tail = max(1, round(0.5 / env.dt_s))
    seen: list[float] = []
    for k in range(ticks):
        X_next = goal if how == "command" else goal_seeking_step(X, goal, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        state = env.step()
        X = state.palm
        if k >= ticks - tail:
            seen.append(float(np.linalg.norm(X.position - goal.position)))
            if on_settled is not None:
                on_settled(state)
    return seen


def measure_steady(
    desc: RobotDescription,
    placement: Placement,
    config: RobotConfig | None = None,
    goals: dict[str, tuple[Array, Array]] | None = None,
) -> list[Steady]:
    """The palm's steady-state error at `steady_goals` (module docstring), or at `goals`
    (name -> (p, R), base frame)."""
    out = []
    chain = arm_chain(desc)
    if goals is None:
        R_down = placement.rotation(R_PALM_DOWN)
        goals = {n: (p, R_down) for n, p in steady_goals(placement).items()}
    for name, (p_goal, R_goal) in goals.items():
        if not reach_pose(chain, desc, name, (p_goal, R_goal), config).reachable:
            out.append(Steady(name, math.nan, math.nan, False, tried=False))
            continue
        errors: dict[str, float] = {}
        touched: list[bool] = []  # each settled tick, of either way of holding

        def note(state: BulletArmState, into: list[bool] = touched) -> None:
            into.append(bool(state.contacts))

        for how in ("command", "seek"):
            cfg = EnvConfig(description=desc, placement=placement, robot=config or RobotConfig())
            with KitchenEnv(noise_free(cfg)) as env:
                goal = HandState(p_goal, R_goal, np.ones(len(desc.fingers)))
                seen = hold_still(env, goal, how, note)
                errors[how] = float(np.mean(seen))
        contact = any(touched)
        forced = (config or RobotConfig()).gravity_compensation
        gc = desc.gravity_compensation if forced is None else bool(forced)
        out.append(Steady(name, errors["command"], errors["seek"], contact, True, gc))
    return out


def measure_grasp(
    desc: RobotDescription,
    placement: Placement,
    utensil: str,
    config: RobotConfig | None = None,
) -> Grasp:
    """Close on `utensil` at its grasp pose and lift (module docstring)."""
    cfg = EnvConfig(description=desc, placement=placement, robot=config or RobotConfig())
    cfg = dataclasses.replace(
        cfg, task=dataclasses.replace(cfg.task, timeout_s=GRASP_WITHIN_S + LIFT_S + 1.0)
    )
    with KitchenEnv(noise_free(cfg)) as env:
        state = env.reset(utensil)
        task = env.task
        z0 = float(env.utensil_pose()[0][2])
        X = state.palm
        grasped_s = None
        after = 0
        lift_ticks = round(LIFT_S / env.dt_s)
        for _ in range(round((GRASP_WITHIN_S + LIFT_S) / env.dt_s)):
            if task.phase == Phase.DONE:
                break
            X_next = goal_seeking_step(X, task.goal, env.dt_s)
            env.set_target(X_next.position, X_next.rotation, X_next.openness)
            state = env.step()
            X = state.palm
            if grasped_s is None:
                if any(e.kind == EventKind.GRASP for e in env.last_events):
                    grasped_s = state.t_s
                elif state.t_s >= GRASP_WITHIN_S:
                    break
            else:
                after += 1
                if after >= lift_ticks:
                    break
        uid = env.world.utensils[utensil]
        held = grasped_s is not None and env._holds(state, utensil) and after >= lift_ticks
        lift = float(env.utensil_pose()[0][2]) - z0
        force = sum(
            c.normal_force_n
            for c in state.contacts
            if c.other_body == uid and c.robot_link in env.robot.link_group
        )
    return Grasp(utensil, True, grasped_s, held, lift, float(force))


def check(desc: RobotDescription, config: RobotConfig | None = None) -> Report:
    """Every check of the module docstring for `desc`."""
    cfg = config or RobotConfig()
    placement = task_placement(desc, cfg)
    reaches = reach_all(arm_chain(desc), desc, placement, cfg)
    found = problems(desc, placement, reaches)
    steady = measure_steady(desc, placement, cfg)
    for s in steady:
        if not s.tried:
            found.append(
                f"steady state: the still pose {s.goal!r} (palm down) is out of reach, not "
                "measured; fix: stand the scene where the arm reaches it ([task] xyz_m)"
            )
        elif not s.ok:
            found.append(
                f"steady state: the palm stays {1e3 * max(s.command_m, s.seek_m):.2f} mm from "
                f"a still pose ({s.goal}; commanded {1e3 * s.command_m:.2f} mm, goal-seeking "
                f"{1e3 * s.seek_m:.2f} mm; pass <= {1e3 * STEADY_TOL_M:g} mm); fix: let the "
                "arm hold its own weight ([arm] gravity_compensation = true, the default) "
                "and raise arm.position_gain towards 1"
            )
    reachable = {r.name: r.reachable for r in reaches}
    grasps = []
    for name in UTENSIL_NAMES:
        if not reachable[f"grasp {name}"]:
            grasps.append(Grasp(name, False, None, False, 0.0, 0.0))
            continue
        g = measure_grasp(desc, placement, name, cfg)
        grasps.append(g)
        if not g.ok:
            what = (
                "never closed on it"
                if g.grasped_s is None
                else f"dropped it within {LIFT_S:g} s of the grasp"
                if not g.held_after_lift
                else f"lifted it only {1e3 * g.lift_m:.0f} mm"
            )
            found.append(
                f"grasp {name}: the gripper {what}; fix: check [grip] tcp_xyz_m and depth_m "
                "(the grasp frame between the pads, on the grip), the fingers' closed "
                "positions (past the 24 mm grip) and force"
            )
    return Report(desc, placement, reaches, steady, grasps, derived_values(desc), found)
