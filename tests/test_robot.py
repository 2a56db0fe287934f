"""The robot package: kinematics, control, grasping, the pick-and-place task, viewer export."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterator

import numpy as np
import pybullet as pb
import pytest
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState, so3_exp, so3_log
from dsteleop.errors import DsteleopError
from dsteleop.robot.arm import BulletArmState, RobotConfig
from dsteleop.robot.env import R_PALM_DOWN, EnvConfig, KitchenEnv
from dsteleop.robot.hand_urdf import (
    ASSET_PATH,
    FINGER_NAMES,
    JOINT_OPEN_CLOSED_RAD,
    build_hand_urdf,
)
from dsteleop.robot.kinematics import ArmChain
from dsteleop.robot.model import ARM_JOINTS, robot_urdf_text
from dsteleop.robot.perception import PerceptionError
from dsteleop.robot.scripted import goal_seeking_step, noise_free, run_autonomous
from dsteleop.robot.task import EventKind, Phase, TaskConfig
from dsteleop.robot.world import UTENSIL_NAMES, R_from_quat_xyzw

Array = NDArray[np.float64]


@pytest.fixture(scope="module")
def env() -> Iterator[KitchenEnv]:
    e = KitchenEnv(noise_free())
    yield e
    e.close()


def _hold(env: KitchenEnv, p: Array, R: Array, g: Array, ticks: int) -> BulletArmState:
    state = env.state()
    for _ in range(ticks):
        env.set_target(p, R, g)
        state = env.step()
    return state


def _pose_error(state: BulletArmState, p: Array, R: Array) -> tuple[float, float]:
    e_p = float(np.linalg.norm(state.palm.position - p))
    e_r = float(np.linalg.norm(so3_log(R @ state.palm.rotation.T)))
    return e_p, e_r


# ---------------------------------------------------------------------------- hand model
def test_hand_urdf_asset_is_generated_by_its_script() -> None:
    assert ASSET_PATH.read_text() == build_hand_urdf()


def test_hand_has_four_named_fingers_of_two_joints_and_an_opposing_thumb() -> None:
    root = ET.fromstring(build_hand_urdf())
    joints = {j.get("name"): j for j in root.iter("joint")}
    assert FINGER_NAMES == ("thumb", "index", "middle", "ring")
    for f in FINGER_NAMES:
        names = [n for n in joints if n is not None and n.startswith(f"{f}_")]
        assert sorted(names) == [f"{f}_mcp", f"{f}_pip"]
        for n in names:
            assert joints[n].get("type") == "revolute"
            lim = joints[n].find("limit")
            assert lim is not None
            lo, hi = float(lim.get("lower", "nan")), float(lim.get("upper", "nan"))
            assert sorted(JOINT_OPEN_CLOSED_RAD[n]) == pytest.approx([lo, hi])

    def base_y(f: str) -> float:
        o = joints[f"{f}_mcp"].find("origin")
        assert o is not None
        return float(o.get("xyz", "0 0 0").split()[1])

    def axis_x(f: str) -> float:
        a = joints[f"{f}_mcp"].find("axis")
        assert a is not None
        return float(a.get("xyz", "0 0 0").split()[0])

    # the thumb sits across the palm from the three fingers and flexes towards them
    for f in ("index", "middle", "ring"):
        assert np.sign(base_y(f)) == -np.sign(base_y("thumb"))
        assert np.sign(axis_x(f)) == -np.sign(axis_x("thumb"))


# ---------------------------------------------------------------------------- kinematics
def test_numpy_fk_matches_pybullet_at_random_joint_positions() -> None:
    text = robot_urdf_text()
    chain = ArmChain.from_urdf(text, ARM_JOINTS, "flange_to_palm")
    with KitchenEnv() as e:
        e.reset("spoon", seed=0)
        body, c = e.robot.body, e.client
        links = {
            pb.getJointInfo(body, j, physicsClientId=c)[12].decode(): j
            for j in range(pb.getNumJoints(body, physicsClientId=c))
        }
        joints = {
            pb.getJointInfo(body, j, physicsClientId=c)[1].decode(): j
            for j in range(pb.getNumJoints(body, physicsClientId=c))
        }
        rng = np.random.default_rng(7)
        for _ in range(5):
            q = rng.uniform(chain.lower_rad, chain.upper_rad)
            for name, v in zip(ARM_JOINTS, q, strict=True):
                pb.resetJointState(body, joints[name], float(v), physicsClientId=c)
            ls = pb.getLinkState(
                body, links["palm"], computeForwardKinematics=True, physicsClientId=c
            )
            p, R = chain.fk(q)
            assert np.allclose(p, ls[4], atol=1e-6)
            assert np.allclose(R, R_from_quat_xyzw(ls[5]), atol=1e-6)


REACHABLE = [
    ((0.50, 0.00, 0.30), (0.0, 0.0, 0.0)),
    ((0.60, 0.30, 0.25), (0.2, 0.0, 0.0)),
    ((0.45, -0.30, 0.45), (0.0, -0.3, 0.4)),
    ((0.70, 0.10, 0.20), (0.0, 0.25, -0.6)),
]


@pytest.mark.parametrize(("p", "rv"), REACHABLE)
def test_achieved_palm_pose_matches_commanded_pose_after_convergence(
    env: KitchenEnv, p: tuple[float, ...], rv: tuple[float, ...]
) -> None:
    env.reset("spoon", seed=0)
    p_cmd = np.array(p)
    R_cmd = so3_exp(np.array(rv)) @ R_PALM_DOWN
    # approach along the goal-seeking policy (as the loop does), then hold the target
    X = env.state().palm
    goal = HandState(p_cmd, R_cmd, np.ones(4))
    for _ in range(150):
        X_next = goal_seeking_step(X, goal, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
    state = _hold(env, p_cmd, R_cmd, np.ones(4), 30)
    e_p, e_r = _pose_error(state, p_cmd, R_cmd)
    assert e_p < 0.001, f"position error {e_p * 1e3:.2f} mm"
    assert e_r < np.radians(0.5), f"orientation error {np.degrees(e_r):.2f} deg"
    assert not state.target_clamped
    assert not state.unreachable


@pytest.mark.parametrize("p", [(2.0, 0.0, 0.3), (0.5, 0.0, -0.6), (0.4, 1.5, 1.5)])
def test_unreachable_target_is_clamped_and_reported_without_nan(
    env: KitchenEnv, p: tuple[float, ...]
) -> None:
    env.reset("spoon", seed=0)
    p_cmd = np.array(p)
    state = _hold(env, p_cmd, R_PALM_DOWN, np.ones(4), 45)
    assert state.target_clamped
    assert state.palm.is_finite()
    assert np.isfinite(list(state.joint_positions_rad.values())).all()
    assert np.isfinite(state.openness_measured).all()
    ws = env.robot.workspace
    clamped, moved = ws.clamp(p_cmd)
    assert moved
    # the robot went to (or towards) the clamped target, not beyond the workspace
    assert np.linalg.norm(state.palm.position - clamped) < np.linalg.norm(
        state.palm.position - p_cmd
    )
    assert np.linalg.norm(state.palm.position - np.asarray(ws.shoulder_m)) <= ws.reach_m + 0.01


def test_orientation_out_of_reach_is_reported_unreachable(env: KitchenEnv) -> None:
    env.reset("spoon", seed=0)
    # palm pointing up, 5 cm above the table, far out: no posture of the iiwa gets there
    R_up = np.diag([1.0, 1.0, 1.0])
    state = _hold(env, np.array([0.9, 0.0, 0.05]), R_up, np.ones(4), 30)
    assert state.unreachable
    assert state.ik_error_m > 0.0 or state.ik_error_rad > 0.0
    assert state.palm.is_finite()


def test_bad_inputs_raise_one_line_errors(env: KitchenEnv) -> None:
    env.reset("spoon", seed=0)
    with pytest.raises(DsteleopError):
        env.set_target(np.array([np.nan, 0.0, 0.3]), R_PALM_DOWN, np.ones(4))
    with pytest.raises(DsteleopError):
        env.set_target(np.array([0.5, 0.0, 0.3]), R_PALM_DOWN, np.ones(3))
    with pytest.raises(DsteleopError):
        env.set_target(np.array([0.5, 0.0, 0.3]), np.eye(3) * 2.0, np.ones(4))
    with pytest.raises(DsteleopError):
        env.reset("fork", seed=0)
    with pytest.raises(DsteleopError):
        RobotConfig(substeps=0)
    with pytest.raises(DsteleopError):
        TaskConfig(goal_noise_pos_m=-1.0)
    for msg in ("position must be finite",):
        try:
            env.set_target(np.array([np.inf, 0.0, 0.3]), R_PALM_DOWN, np.ones(4))
        except DsteleopError as exc:
            assert msg in str(exc) and "\n" not in str(exc)


# ---------------------------------------------------------------------------- fingers
@pytest.mark.parametrize("g", [0.0, 1.0])
def test_openness_zero_and_one_reach_the_joint_limits(env: KitchenEnv, g: float) -> None:
    env.reset("spoon", seed=0)
    home = np.asarray(env.config.home_position_m)
    state = _hold(env, home, R_PALM_DOWN, np.full(4, g), 45)
    assert not state.contacts, "the hand must be in free space for this test"
    for name, (q_open, q_closed) in JOINT_OPEN_CLOSED_RAD.items():
        expected = q_open if g == 1.0 else q_closed
        assert state.joint_positions_rad[name] == pytest.approx(expected, abs=0.02), name
    assert state.openness_measured == pytest.approx(np.full(4, g), abs=0.02)
    assert state.grasped is None  # closing on nothing never engages the grasp helper


def test_grasp_helper_engages_only_on_real_contact_of_thumb_and_closed_fingers() -> None:
    cfg = noise_free(EnvConfig(robot=RobotConfig(grasp_helper=True)))
    with KitchenEnv(cfg) as env:
        _check_helper(env)


def _check_helper(env: KitchenEnv) -> None:
    env.reset("spoon", seed=0)
    p, R = env.task.pick_true
    X = env.state().palm
    at_grasp = HandState(p, R, np.ones(4))
    for _ in range(120):
        X_next = goal_seeking_step(X, at_grasp, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
    # fingers closed, thumb open: the fingers press the grip, nothing opposes them
    state = _hold(env, p, R, np.array([1.0, 0.0, 0.0, 0.0]), 20)
    assert any(c.other_name == "spoon" for c in state.contacts)
    assert state.grasped is None
    # the thumb closes too: the grip is pinched, the helper holds it
    state = _hold(env, p, R, np.zeros(4), 40)
    thumb_touch = {c.robot_link for c in state.contacts if c.other_name == "spoon"}
    assert any(link.startswith("thumb") for link in thumb_touch)
    assert state.grasped == "spoon"
    # opening lets go
    state = _hold(env, p, R, np.ones(4), 5)
    assert state.grasped is None


# ---------------------------------------------------------------------------- task
@pytest.mark.parametrize("utensil", UTENSIL_NAMES)
def test_scripted_autonomous_run_succeeds_for_every_utensil(env: KitchenEnv, utensil: str) -> None:
    result = run_autonomous(env, utensil, seed=0)
    assert result.outcome.success, result.outcome
    assert result.outcome.reason == "in_bin"
    kinds = [e.kind for e in result.events]
    assert kinds == [
        EventKind.GOAL,
        EventKind.GRASP,
        EventKind.GOAL,
        EventKind.RELEASE,
        EventKind.SUCCESS,
    ]
    assert result.outcome.time_s == pytest.approx(result.sim_time_s, abs=env.dt_s)
    assert env.task.phase == Phase.DONE
    # the utensil lies in the bin, the others still stand in the holder
    p, _ = env.utensil_pose(utensil)
    assert env.task.regions.bin_inner.contains(p)
    for other in UTENSIL_NAMES:
        if other != utensil:
            assert env.task.regions.holder.contains(env.utensil_pose(other)[0])


def test_x_start_resets_when_the_place_goal_activates(env: KitchenEnv) -> None:
    env.reset("spatula", seed=0)
    task = env.task
    assert task.X_start is not None
    start_pick = task.X_start
    X = env.state().palm
    while task.phase == Phase.PICK:
        X_next = goal_seeking_step(X, task.goal, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
    assert task.phase == Phase.PLACE
    assert task.X_start is not start_pick
    assert np.allclose(task.X_start.position, X.position)
    assert np.allclose(task.goal.position, task.place_known[0])
    assert task.goal.openness == pytest.approx(np.zeros(4))  # keep holding on the way


def test_utensil_dropped_on_the_table_is_a_failure(env: KitchenEnv) -> None:
    env.reset("ladle", seed=0)
    task = env.task
    X = env.state().palm
    while task.phase == Phase.PICK:
        X_next = goal_seeking_step(X, task.goal, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
    # carry it over the open table (between holder and bin) and let go there
    over_table = HandState(np.array([0.40, 0.05, 0.40]), R_PALM_DOWN, np.zeros(4))
    for _ in range(90):
        X_next = goal_seeking_step(X, over_table, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
    # carried by friction alone: the ladle hangs under the palm, clear of the table
    p_ladle, _ = env.utensil_pose("ladle")
    assert np.linalg.norm(p_ladle[:2] - X.position[:2]) < 0.08 and p_ladle[2] > 0.15
    opened = HandState(over_table.position, R_PALM_DOWN, np.ones(4))
    for _ in range(300):
        X_next = goal_seeking_step(X, opened, env.dt_s)
        env.set_target(X_next.position, X_next.rotation, X_next.openness)
        X = env.step().palm
        if task.outcome is not None:
            break
    assert task.outcome is not None
    assert not task.outcome.success
    assert task.outcome.reason == "on_table"
    assert [e.kind for e in task.events][-2:] == [EventKind.RELEASE, EventKind.FAILURE]


def test_timeout_is_a_failure() -> None:
    cfg = EnvConfig(task=TaskConfig(timeout_s=1.0))
    with KitchenEnv(cfg) as e:
        e.reset("spoon", seed=0)
        home = np.asarray(cfg.home_position_m)
        _hold(e, home, R_PALM_DOWN, np.ones(4), 40)
        assert e.task.outcome is not None
        assert e.task.outcome.reason == "timeout"
        assert e.task.outcome.time_s == pytest.approx(1.0, abs=0.05)


def test_same_seed_gives_the_same_run_and_other_seeds_other_goals() -> None:
    with KitchenEnv() as e:  # default config: noisy goals
        a = run_autonomous(e, "spoon", seed=3)
        goals_a = (e.task.pick_known[0].copy(), e.task.place_known[0].copy())
        b = run_autonomous(e, "spoon", seed=3)
        goals_b = (e.task.pick_known[0].copy(), e.task.place_known[0].copy())
        e.reset("spoon", seed=4)
        goals_c = (e.task.pick_known[0].copy(), e.task.place_known[0].copy())
    assert a.outcome == b.outcome
    assert a.events == b.events
    assert a.ticks == b.ticks
    assert all(np.array_equal(x, y) for x, y in zip(goals_a, goals_b, strict=True))
    assert not np.allclose(goals_a[0], goals_c[0])
    # the noise is there: the known pick goal differs from the true one
    assert np.linalg.norm(goals_a[0] - e.task.pick_true[0]) > 0.0


# ---------------------------------------------------------------------------- viewer export
def test_scene_export_covers_every_body_and_link_with_finite_poses(env: KitchenEnv) -> None:
    env.reset("spoon", seed=0)
    geo = env.geometry()
    poses = env.poses()
    n = len(geo.frames)
    assert poses.positions_m.shape == (n, 3) and poses.wxyz.shape == (n, 4)
    assert np.isfinite(poses.positions_m).all() and np.isfinite(poses.wxyz).all()
    assert np.allclose(np.linalg.norm(poses.wxyz, axis=1), 1.0, atol=1e-6)
    frames_with_visuals = {v.frame for v in geo.visuals}
    for name in (
        "table",
        "holder",
        "bin",
        "floor",
        *UTENSIL_NAMES,
        "robot/palm",
        "robot/lbr_iiwa_link_0",
        "robot/lbr_iiwa_link_7",
        *(f"robot/{f}_{s}" for f in FINGER_NAMES for s in ("proximal", "distal")),
    ):
        assert name in geo.frames
        assert name in frames_with_visuals
    for v in geo.visuals:
        if v.kind == "mesh":
            assert v.mesh_path is not None
            with open(v.mesh_path, "rb"):
                pass
        assert len(v.rgba) == 4 and all(0.0 <= c <= 1.0 for c in v.rgba)
    # the palm frame's pose equals the achieved palm pose
    i = geo.frames.index("robot/palm")
    state = env.state()
    assert np.allclose(poses.positions_m[i], state.palm.position, atol=1e-9)
    w, x, y, z = poses.wxyz[i]
    assert np.allclose(R_from_quat_xyzw((x, y, z, w)), state.palm.rotation, atol=1e-9)
    # a utensil frame moves with its body
    j = geo.frames.index("spoon")
    assert np.allclose(poses.positions_m[j], env.utensil_pose("spoon")[0])


def test_scene_types_import_without_pybullet() -> None:
    code = (
        "import sys; import dsteleop.robot.scene as s; "
        "assert 'pybullet' not in sys.modules, 'pybullet imported'; print('ok')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert out.returncode == 0, out.stderr


def test_a_robot_not_told_its_utensil_makes_the_one_it_grasps_the_tasks() -> None:
    """`EnvConfig.infer`: every utensil a candidate; the robot seeks one the person did not
    intend (the candidates' own goals and finger schedules), and the grasp makes it the
    task's: it is judged in the bin, the intended one stays in the holder."""
    cfg = dataclasses.replace(EnvConfig(), infer=True, perception=PerceptionError(0.0, 0.0, 0.0))
    with KitchenEnv(cfg) as env:
        X = env.reset(utensil="spoon", seed=0).palm
        task = env.task
        while task.outcome is None:
            c = task.candidates()
            k = c.names.index("ladle") if c is not None and "ladle" in c.names else 0
            X_goal = task.goal if c is None else c.goals.take(k)  # the bin: the one candidate
            X_next = goal_seeking_step(X, X_goal, env.dt_s)
            env.set_target(X_next.position, X_next.rotation, X_next.openness)
            X = env.step().palm
        assert task.outcome.success and task.outcome.utensil == "ladle", task.outcome
        assert [e.detail for e in task.events if e.kind is EventKind.GRASP] == ["ladle"]
        assert task.intended == "spoon"
        p, _ = env.utensil_pose("spoon")
        assert p[1] > 0.15  # still in the holder


def test_a_kitchen_not_told_its_utensil_rebuilds_from_what_it_records() -> None:
    """The kitchen task records whether its robot is told and how it perceives: a replay
    rebuilds the same candidates (`task_options_from_meta`), and `--goal-noise` makes the
    candidates' error isotropic."""
    from dsteleop.app.plants.kitchen import KitchenTask, task_options_from_meta

    a = KitchenTask(utensil="ladle", seed=4, infer=True, twin=False)
    try:
        a.reset()
        meta = a.describe()
        assert meta["goal"] == "infer" and meta["perception"]["depth_sigma_m"] == 0.02
        assert a.goal() is None and a.candidates() is not None
        b = KitchenTask(twin=False, **task_options_from_meta(meta))
        try:
            b.reset()
            ca, cb = a.candidates(), b.candidates()
            assert ca is not None and cb is not None
            assert np.array_equal(ca.goals.position, cb.goals.position)
            assert np.array_equal(ca.sigma, cb.sigma)
        finally:
            b.close()
        a.set_goal_noise(0.03)
        a.reset()
        c = a.candidates()
        assert c is not None and np.allclose(c.sigma[:, :3], 0.03)
    finally:
        a.close()
    told = KitchenTask(utensil="ladle", seed=4, twin=False)
    try:
        told.reset()
        assert told.candidates() is None and told.describe()["goal"] == "ladle"
        assert task_options_from_meta(told.describe())["infer"] is False
    finally:
        told.close()
