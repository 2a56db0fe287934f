"""Robots as descriptions (docs/robots.md) and the Robot and Task ports: the shipped iiwa and
Panda, bad descriptions, a gripper of one finger through the loop, a lost robot, a robot
judged through its twin, and the demo's success rates on both robots."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dsteleop.app.ports import ROBOT_LOST, RobotLimits
from dsteleop.arbitration import HandState, Mode, so3_exp
from dsteleop.errors import InputError
from dsteleop.robot.description import (
    ROBOTS_DIR,
    description_from_record,
    load_description,
    shipped_robots,
)
from dsteleop.tracking.mapping import finger_mix, human_openness, robot_openness
from tests.deadlines import wait_for

REPO = Path(__file__).resolve().parents[1]


def test_the_shipped_robots_load_and_the_iiwa_is_todays_arm_and_hand() -> None:
    from dsteleop.robot.hand_urdf import FINGER_NAMES, JOINT_OPEN_CLOSED_RAD
    from dsteleop.robot.model import ARM_JOINTS, FLANGE_TO_PALM_M

    assert set(shipped_robots()) >= {"iiwa", "panda"}
    iiwa = load_description("iiwa")
    assert iiwa.finger_names == FINGER_NAMES and iiwa.arm_joints == ARM_JOINTS
    assert {j.name: (j.open, j.closed) for j in iiwa.finger_joints} == JOINT_OPEN_CLOSED_RAD
    assert iiwa.mount is not None and iiwa.mount.xyz_m == (0.0, 0.0, FLANGE_TO_PALM_M)
    assert iiwa.palm_frame_link == "palm" and iiwa.opposing == "thumb"
    panda = load_description(str(ROBOTS_DIR / "panda.toml"))  # by file, too
    assert panda.finger_names == ("gripper",) and panda.fingers[0].human == ("thumb", "index")
    assert {j.group for j in panda.finger_joints} == {"left", "right"}
    assert load_description("panda") == panda


def test_the_grasp_goal_puts_each_robots_grasp_frame_on_the_grip() -> None:
    """The iiwa's grasp frame is its palm, 12 mm above the grip's top (as before robots had
    grasp frames, to the bit); the Panda's is between its pads, 2 cm into the grip."""
    from dsteleop.robot.world import UTENSIL_LENGTH_M, UTENSILS, T_utensil_grasp

    iiwa, panda = load_description("iiwa"), load_description("panda")
    assert iiwa.grasp_xyz_m == (0.0, 0.0, 0.0) and iiwa.grasp_depth_m == -0.012
    assert panda.grasp_xyz_m == (0.0, 0.0, 0.0374) and panda.grasp_depth_m == 0.020
    for spec in UTENSILS.values():
        top = np.array([0.0, 0.0, UTENSIL_LENGTH_M]) - spec.com_m()  # the grip's top, COM frame
        p, R = T_utensil_grasp(spec, iiwa.grasp_xyz_m, iiwa.grasp_depth_m)
        assert (
            p.tobytes() == (np.array([0.0, 0.0, UTENSIL_LENGTH_M + 0.012]) - spec.com_m()).tobytes()
        )
        p, R = T_utensil_grasp(spec, panda.grasp_xyz_m, panda.grasp_depth_m)
        assert np.allclose(R[:, 2], [0.0, 0.0, -1.0])  # palm z down the handle
        tcp = p + R @ np.array(panda.grasp_xyz_m)
        assert np.allclose(tcp, top - np.array([0.0, 0.0, 0.020]))
        face = top + np.array([0.0, 0.0, 0.0374 - 0.020])  # the hand's face 17 mm above
        assert np.allclose(p, face)


def test_a_session_without_a_robot_means_the_iiwa_and_a_recorded_one_comes_back() -> None:
    assert description_from_record(None).name == "iiwa"
    assert description_from_record({"kind": "simulated"}).name == "iiwa"
    panda = load_description("panda")
    again = description_from_record({"description": panda.to_dict()})
    assert again == panda


_GOOD = (ROBOTS_DIR / "panda.toml").read_text()
BAD = {
    "malformed": _GOOD.replace('name = "panda"', 'name = "panda'),
    "missing link": _GOOD.replace('link = "panda_hand"', 'link = "panda_wrist"'),
    "unknown joint": _GOOD.replace('"panda_finger_joint2"', '"panda_finger_joint9"'),
    "missing field": _GOOD.replace("reach_m = 0.80\n", ""),
    "not revolute": _GOOD.replace('"panda_joint7"]', '"panda_joint8"]'),
    "urdf": _GOOD.replace("franka_panda/panda.urdf", "franka_panda/none.urdf"),
    "grasp frame": _GOOD.replace("tcp_xyz_m = [0.0, 0.0, 0.0374]", "tcp_xyz_m = [0.0, 0.0374]"),
    "friction": _GOOD.replace("spinning_friction = 0.1", "spinning_friction = -0.1"),
    "squeeze": _GOOD.replace("squeeze_share = 0.05", "squeeze_share = 2.0"),
}
WORDS = {
    "malformed": "not valid TOML",
    "missing link": "palm.link",
    "unknown joint": "panda_finger_joint9",
    "missing field": "limits.reach_m is missing",
    "not revolute": "not revolute",
    "urdf": "arm.urdf",
    "grasp frame": "grip.tcp_xyz_m must be 3 finite numbers",
    "friction": "grip.spinning_friction must be in [0, 1], got -0.1",
    "squeeze": "fingers[0].squeeze_share must be in (0, 1], got 2.0",
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_robot_description_is_one_clear_error(case: str, tmp_path: Path) -> None:
    path = tmp_path / f"{case.replace(' ', '_')}.toml"
    path.write_text(BAD[case])
    with pytest.raises(InputError) as err:
        load_description(str(path))
    message = str(err.value)
    assert "\n" not in message and str(path) in message and WORDS[case] in message
    with pytest.raises(InputError, match="unknown robot 'nosuch'"):
        load_description("nosuch")


@pytest.mark.parametrize("case", ["missing link", "unknown joint", "malformed"])
def test_the_cli_says_a_bad_description_in_one_line_exit_2_and_records_nothing(
    case: str, tmp_path: Path
) -> None:
    path = tmp_path / "arm.toml"
    path.write_text(BAD[case])
    record = tmp_path / "session"
    r = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "run", "--source", "demo",
         "--robot", str(path), "--record", str(record)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and WORDS[case] in lines[0] and "Traceback" not in r.stderr
    assert not record.exists()  # refused before anything ran or recorded


def test_robot_limits_clamp_the_command_into_the_box_and_the_speeds() -> None:
    lim = RobotLimits((0.0, -1.0, 0.0), (1.0, 1.0, 1.0), 0.3, 1.0, 4.0)
    X0 = HandState(np.array([0.5, 0.0, 0.5]), np.eye(3), np.array([1.0]))
    far = HandState(np.array([0.5, 0.0, 2.0]), so3_exp(np.array([0.0, 0.0, 1.0])), np.array([0.0]))
    X = lim.clamp(X0, far, 0.1)
    assert np.linalg.norm(X.position - X0.position) == pytest.approx(0.03)
    from dsteleop.arbitration.se3 import so3_log

    assert np.linalg.norm(so3_log(X.rotation @ X0.rotation.T)) == pytest.approx(0.1)
    assert X.openness[0] == pytest.approx(0.6)
    outside = HandState(np.array([1.2, 0.0, 0.5]), np.eye(3), np.array([1.0]))
    start = HandState(np.array([0.99, 0.0, 0.5]), np.eye(3), np.array([1.0]))
    assert lim.clamp(start, outside, 1.0).position[0] == 1.0
    np.testing.assert_allclose(lim.clamp(X0, X0, 0.1).position, X0.position)


def test_a_gripper_takes_the_pinch_and_the_demo_hand_maps_back_exactly() -> None:
    panda, iiwa = load_description("panda"), load_description("iiwa")
    for desc in (panda, iiwa):
        mix = finger_mix(tuple((f.name, f.human) for f in desc.fingers))
        g = np.linspace(0.1, 0.9, len(desc.fingers))
        np.testing.assert_allclose(robot_openness(human_openness(g, mix), mix), g)
    mix = finger_mix(tuple((f.name, f.human) for f in panda.fingers))
    pinch = np.array([0.0, 0.0, 1.0, 1.0, 1.0])  # thumb and index closed, the rest open
    assert robot_openness(pinch, mix) == pytest.approx([0.0])


def test_the_loop_drives_a_gripper_of_one_finger_and_halts_a_lost_robot_without_pybullet() -> None:
    """In a subprocess: the loop with a one-finger fake robot and fake task reaches the task's
    outcome in DS, and a robot that stops reporting is halted like a lost hand; pybullet is
    never imported."""
    code = (
        "import sys\n"
        "from tests.test_robots import gripper_runs_and_a_lost_robot_halts as f\n"
        "f()\n"
        "heavy = [m for m in ('pybullet', 'pybullet_data', 'zenoh') if m in sys.modules]\n"
        "print(heavy)\n"
        "assert not heavy, heavy\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "[]"


def gripper_runs_and_a_lost_robot_halts() -> None:
    from dsteleop.app.loop import LoopConfig, TeleopLoop
    from dsteleop.app.loop.timing import ManualClock
    from dsteleop.app.session.schema import Status
    from tests.fakes import DT, FakeRobot, FakeTask, ScriptedHand, state

    start = state((0.5, 0.3, 0.4), n_fingers=1)
    robot = FakeRobot(start, fingers=("gripper",))
    task = FakeTask(n_fingers=1)

    def reach(t: float) -> HandState:  # the operator's hand: to the pick, close, to the place
        legs = ((start, task.pick, 0.5, 3.5), (task.pick, task.place, 5.0, 8.0))
        X = start
        for a, b, t0, t1 in legs:
            s = min(max((t - t0) / (t1 - t0), 0.0), 1.0)
            if t >= t0:
                X = HandState(a.position + s * (b.position - a.position), a.rotation, b.openness)
        return X

    loop = TeleopLoop(LoopConfig(mode=Mode.DS), ScriptedHand(reach), robot, task, ManualClock(0.0))
    assert loop.dims[6:] == ("gripper",)
    for k in range(30 * 60):
        loop.tick(k * DT)
        if loop.outcome:
            break
    assert loop.outcome == "success", "the policy carries the gripper to both goals"
    assert all(c.openness.shape == (1,) for c in robot.commands)
    assert robot.seqs == list(range(1, len(robot.seqs) + 1))  # one more per tick

    # A robot that stops reporting after 20 commands: halted within 0.2 s of its last state
    # plus the halt ramp, the status says why, and the task is not judged meanwhile.
    start = state((0.5, 0.3, 0.4))
    robot = FakeRobot(start, silent_after=20)
    task = FakeTask()
    moving = lambda t: state((0.5, 0.3 - 0.05 * t, 0.4))  # noqa: E731
    cfg = LoopConfig(mode=Mode.MANUAL)
    loop = TeleopLoop(cfg, ScriptedHand(moving), robot, task, ManualClock(0.0))
    records = [loop.tick(k * DT) for k in range(60)]
    t_last = 20 * DT  # the stamp of the last state
    lost = [r for r in records if r.reason == ROBOT_LOST]
    assert lost and lost[0].t_s <= t_last + 0.2 + 2 * DT
    assert all(r.status is Status.LOST for r in lost)
    done = [r for r in lost if r.t_s >= lost[0].t_s + cfg.halt_ramp_s + DT]
    assert done and all(float(np.abs(r.U_cmd).max()) == 0.0 for r in done)
    assert task.updates < len(records)


@pytest.mark.slow
def test_a_twin_judges_a_robot_outside_the_task_world() -> None:
    """A PyBullet robot in a world of its own (as the far end of a link), judged by the
    kitchen task through its twin: the goal-seeking run (noise-free) puts the spoon in the
    bin, for both robots."""
    from dsteleop.app.plants.kitchen import KitchenTask
    from dsteleop.app.plants.simulated import SimulatedRobot
    from dsteleop.robot.scripted import goal_seeking_step

    for name in ("iiwa", "panda"):
        desc = load_description(name)
        robot = SimulatedRobot.alone(desc)
        task = KitchenTask(desc, goal_noise_m=0.0, goal_noise_rad=0.0, twin=True)
        try:
            task.reset()
            X = robot.reset(0.0).X
            outcome = None
            for k in range(1, 1200):
                goal = task.goal()
                assert goal is not None
                robot.apply(goal_seeking_step(X, goal, 1 / 30), k, k / 30)
                st = robot.state(k / 30)
                assert st is not None and st.joints.shape == (len(robot.joint_names),)
                X = st.X
                outcome = task.update(st).outcome
                if outcome is not None:
                    break
            assert outcome is not None and outcome.success, (name, outcome)
        finally:
            robot.close()
            task.close()


@pytest.mark.slow
def test_the_panda_grasps_every_utensil_on_its_own() -> None:
    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import noise_free, run_autonomous

    with KitchenEnv(noise_free(EnvConfig(description=load_description("panda")))) as env:
        for utensil in ("spoon", "spatula", "ladle"):
            result = run_autonomous(env, utensil, 0)
            assert result.outcome.success, (utensil, result.outcome)


def test_a_panda_session_records_its_robot() -> None:
    from dsteleop.app.compose import LoopOptions, build

    built = build(LoopOptions.of("demo", robot="panda"), realtime=False)
    try:
        meta = built.loop.session_meta()
        assert meta["dims"][6:] == ["gripper"]
        assert meta["robot"]["name"] == "panda"
        assert description_from_record(meta["robot"]).name == "panda"
        assert meta["mapping"]["robot_fingers"] == (("gripper", ("thumb", "index")),)
    finally:
        built.close()


def _demo_successes(mode: Mode, robot: str) -> int:
    from dsteleop.app.compose import LoopOptions, build
    from dsteleop.app.loop import LoopConfig

    n = 0
    for seed in range(10):
        built = build(
            LoopOptions.of("demo", LoopConfig(mode=mode), seed=seed, robot=robot), realtime=False
        )
        try:
            built.loop.run_headless(3700)  # the task's own timeout (120 s) decides
            n += built.loop.outcome == "success"
        finally:
            built.close()
    return n


@pytest.mark.slow
@pytest.mark.parametrize("mode", [Mode.DS, Mode.S, Mode.MANUAL])
def test_the_demo_succeeds_on_the_panda_about_as_often_as_on_the_iiwa(mode: Mode) -> None:
    """Seeds 0-9, the same demo settings: the Panda's successes within 2 of the iiwa's
    (measured 2026-12-03: iiwa 7/7/7, Panda 6/5/9 of 10 in DS/S/manual; docs/robots.md)."""
    iiwa, panda = _demo_successes(mode, "iiwa"), _demo_successes(mode, "panda")
    assert abs(panda - iiwa) <= 2, (mode, iiwa, panda)


def test_the_page_draws_the_panda_and_its_one_gauge_of_fingers() -> None:
    """`serve --robot panda`'s view: a real Viser server follows a live Panda loop; the scene
    is drawn from the Panda's URDF meshes, the gauges have one finger dimension."""
    import time

    from dsteleop.app.compose import LoopOptions, build
    from dsteleop.app.loop.timing import ManualClock
    from dsteleop.app.viewer.server import Viewer, ViewerConfig

    built = build(LoopOptions.of("demo", robot="panda"), realtime=False, export_scene=True)
    loop = built.loop
    viewer = Viewer(loop.broadcaster, loop.controls, loop.task.scene(), ViewerConfig(port=0))
    try:
        viewer.start()
        clock = loop.clock
        assert isinstance(clock, ManualClock)
        for _ in range(90):
            record = loop.tick(clock.now())
            clock.advance(loop.config.dt_s)
            time.sleep(0.005)
        assert record.dims[6:] == ("gripper",) and record.X_current.openness.shape == (1,)
        wait_for(lambda: viewer.stats.panel_updates >= 2)
        assert viewer.stats.scene_updates >= 2 and viewer.stats.errors == 0
        frames = set(viewer.scene.frames)
        assert {"robot/panda_hand", "robot/panda_leftfinger", "robot/panda_rightfinger"} <= frames
    finally:
        viewer.close()
        built.close()


@pytest.mark.parametrize("robot", shipped_robots())
def test_the_palm_reaches_a_still_pose_within_2_mm_on_every_shipped_robot(robot: str) -> None:
    """Every description in robot/robots/ (a new one is covered by adding its file), as it
    ships: the palm commanded to a still pose in free air (over the middle pocket, and the
    place pose, where the robot's placement stands them) ends within 2 mm of it
    (`robot.check.measure_steady`: the mean over the last 0.5 s of 10 s), and so does the
    goal-seeking policy stepping from the achieved palm (as the loop does) when the arm
    holds its own weight (gravity compensation: on unless the description says false). An
    arm that sags under position control (a 6-axis arm's 1.5-2.6 mm, issue 33) needs the
    compensation: without it the policy stops ~15 times the sag short. A robot whose task
    is refused (out of its reach wherever the scene stands) is measured at its home.

    With the compensation forced on, every robot's goal-seeking policy is within 2 mm too:
    the iiwa and the Panda ship without it (their demo rates were measured so; their
    commanded pose is within 0.5 mm), and their policy then stops 1-3 mm (iiwa) and 5-6 mm
    (Panda) short (`scripts/steady_state.py --no-gravity-compensation`)."""
    from dsteleop.robot.arm import RobotConfig
    from dsteleop.robot.check import STEADY_TOL_M, measure_steady
    from dsteleop.robot.placement import SHIPPED
    from dsteleop.robot.reach import home_pose, require_reachable

    desc = load_description(robot)
    goals = None
    try:
        placement = require_reachable(desc)  # the scene where the robot reaches it
    except InputError:  # the task is refused for this robot: its home is a still pose too
        placement, goals = SHIPPED, {"home": home_pose(desc)}
    for s in measure_steady(desc, placement, goals=goals):
        assert s.tried and not s.contact, (robot, s)
        assert s.command_m <= STEADY_TOL_M, (robot, s)
        assert s.seek_m <= STEADY_TOL_M or not desc.gravity_compensation, (robot, s)
        assert s.ok
    for s in measure_steady(desc, placement, RobotConfig(gravity_compensation=True), goals):
        assert s.command_m <= STEADY_TOL_M and s.seek_m <= STEADY_TOL_M, (robot, s)


def test_an_arm_that_sags_holds_its_weight_by_default_and_reaches_the_pose(tmp_path: Path) -> None:
    """An iiwa whose motors hold a tenth as stiffly (position gain 0.03, as a sagging arm's)
    and whose description says nothing of gravity compensation: it is on (the default), and
    the palm commanded to the place pose ends within 2 mm of it; without it the arm sags
    2.45 mm there (the default before issue 33), and `[arm] gravity_compensation` must be a
    boolean (one line otherwise)."""
    from dsteleop.robot.arm import RobotConfig
    from dsteleop.robot.env import R_PALM_DOWN, EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import noise_free

    hand = (ROBOTS_DIR / "../assets/dsteleop_hand.urdf").resolve()
    text = (ROBOTS_DIR / "iiwa.toml").read_text()
    text = text.replace('"../assets/dsteleop_hand.urdf"', f'"{hand}"')
    text = text.replace("gravity_compensation = false\n", "")
    path = tmp_path / "soft.toml"
    path.write_text(text.replace("position_gain = 0.3", "position_gain = 0.03"))
    desc = load_description(str(path))
    assert desc.gravity_compensation
    goal = np.array([0.58, -0.26, 0.45])

    def error_m(gc: bool | None) -> float:
        cfg = EnvConfig(description=desc, robot=RobotConfig(gravity_compensation=gc))
        with KitchenEnv(noise_free(cfg)) as env:
            env.reset("spoon")
            seen = []
            for _ in range(round(10.0 / env.dt_s)):
                env.set_target(goal, R_PALM_DOWN, np.ones(4))
                seen.append(float(np.linalg.norm(env.step().palm.position - goal)))
            return float(np.mean(seen[-15:]))

    assert error_m(None) <= 0.002
    assert error_m(False) > 0.002  # the sag the default removes
    path.write_text(
        text.replace("position_gain = 0.3", 'position_gain = 0.3\ngravity_compensation = "yes"')
    )
    with pytest.raises(InputError) as err:
        load_description(str(path))
    assert "arm.gravity_compensation must be true or false, got 'yes'" in str(err.value)


@pytest.mark.parametrize("robot", shipped_robots())
def test_the_gravity_compensation_makes_the_robot_move_as_without_gravity(robot: str) -> None:
    """The compensation (`BulletArm`: each link's weight upwards at its centre of mass before
    each physics step) is exactly the robot without gravity: from the settled home posture
    with every joint set moving (0.5 rad/s at most), one second of control ticks (3 physics
    steps each) under the motors' hold ends in the same joint positions and velocities as
    the same start with gravity off and no compensation (to 1e-9; measured: bit for bit on
    every shipped robot), while gravity alone moves them 0.9-15 mrad (rad/s) away. A force
    at a link's frame origin rather than its centre of mass, one applied once per tick
    rather than before each physics step, or a link left out fails it. (docs/robots.md: the
    UR5's manual runs lose no more grasps with it than without.)"""
    from dsteleop.robot.arm import RobotConfig
    from dsteleop.robot.bullet import pb
    from dsteleop.robot.env import GRAVITY_MPS2, EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import noise_free

    desc = load_description(robot)
    q0: dict[int, float] = {}
    qd0 = np.random.default_rng(7).uniform(-0.5, 0.5, 64)

    def joints_after(gc: bool, gravity: bool) -> np.ndarray:
        cfg = EnvConfig(description=desc, robot=RobotConfig(gravity_compensation=gc))
        with KitchenEnv(noise_free(cfg)) as env:
            env.reset("spoon")
            body, c = env.robot.body, env.client
            idx = [
                i
                for i in range(pb.getNumJoints(body, physicsClientId=c))
                if pb.getJointInfo(body, i, physicsClientId=c)[2] != pb.JOINT_FIXED
            ]
            if not q0:  # the first run's settled posture is every run's start
                q0.update({i: pb.getJointState(body, i, physicsClientId=c)[0] for i in idx})
            for k, i in enumerate(idx):
                pb.resetJointState(body, i, q0[i], qd0[k], physicsClientId=c)
            pb.setGravity(0.0, 0.0, -GRAVITY_MPS2 if gravity else 0.0, physicsClientId=c)
            for _ in range(round(1.0 / env.dt_s)):
                env.robot.step()
            return np.array([s[:2] for s in pb.getJointStates(body, idx, physicsClientId=c)])

    weightless = joints_after(gc=False, gravity=False)
    assert np.abs(joints_after(gc=True, gravity=True) - weightless).max() <= 1e-9, robot
    assert np.abs(joints_after(gc=False, gravity=True) - weightless).max() > 1e-4, robot
