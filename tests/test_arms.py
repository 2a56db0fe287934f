"""The arms beyond the iiwa and the Panda (docs/robots.md): each shipped description loads from
the package that ships its URDF, a missing package is one line naming the install, and each
arm that can reach the task grasps a utensil on its own (the goal-seeking run, noise-free)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from dsteleop.errors import InputError
from dsteleop.robot.description import DATA_PACKAGES, data_package_dir, load_description

REPO = Path(__file__).resolve().parents[1]

#: Hide example-robot-data from importlib.metadata, as when the `robots` extra is not installed.
_HIDE = """
import sys
from importlib import metadata
_real = metadata.distribution
def _distribution(name):
    if name == "example-robot-data":
        raise metadata.PackageNotFoundError(name)
    return _real(name)
metadata.distribution = _distribution
from dsteleop.app.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def test_the_ur5_is_read_as_shipped_with_the_hand_on_its_flange() -> None:
    """ur5_robot.urdf as example-robot-data ships it: <transmission> blocks name every arm
    joint, and they are not joints; the project's hand is mounted on UR's tool flange."""
    ur5 = load_description("ur5")
    assert ur5.urdf.startswith("example-robot-data:")
    share = data_package_dir("example-robot-data", "test")
    assert ur5.resolve(ur5.urdf) == share / "robots/ur_description/urdf/ur5_robot.urdf"
    assert "<transmission" in ur5.resolve(ur5.urdf).read_text()
    assert len(ur5.arm_joints) == 6 and ur5.mount is not None
    assert (
        ur5.mount.parent_link == "tool0"
        and ur5.finger_names == load_description("iiwa").finger_names
    )


def test_the_xarm_gripper_is_one_drive_joint_and_its_five_mimics() -> None:
    """The xArm Gripper's linkage: the description lists the drive joint only; the URDF's
    five <mimic> joints follow it (multiplier 1), the right side's links in their own group."""
    xarm = load_description("xarm6")
    assert [j.name for j in xarm.finger_joints] == ["drive_joint"]
    mimics = {m.name: (m.master, m.multiplier, m.offset) for m in xarm.mimic_joints}
    assert mimics == {
        n: ("drive_joint", 1.0, 0.0)
        for n in (
            "left_finger_joint",
            "left_inner_knuckle_joint",
            "right_outer_knuckle_joint",
            "right_finger_joint",
            "right_inner_knuckle_joint",
        )
    }
    assert dict(xarm.link_groups) == dict.fromkeys(
        ("right_outer_knuckle", "right_finger", "right_inner_knuckle"), "right"
    )


def test_a_robot_whose_package_is_missing_names_the_install() -> None:
    """Without example-robot-data, `--robot ur5` is one line and exit 2 naming the pip install
    (nothing is downloaded); the library call raises the same InputError."""
    r = subprocess.run(
        [sys.executable, "-c", _HIDE, "run", "--source", "demo", "--robot", "ur5"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "example-robot-data is not installed" in lines[0]
    assert "pip install 'dsteleop[robots]'" in lines[0] and "ur5.toml" in lines[0]


def test_a_data_package_without_its_data_folder_is_one_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(DATA_PACKAGES, "example-robot-data", "cmeel.prefix/share/nowhere")
    with pytest.raises(InputError, match=r"has no cmeel.prefix/share/nowhere") as err:
        load_description("ur5")
    assert "\n" not in str(err.value)


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["ur5", "xarm6"])
def test_each_arm_that_reaches_the_task_grasps_and_places_every_utensil(robot: str) -> None:
    """The goal-seeking run (noise-free goals): the grip closes on each utensil (the task's
    grasp: two contact groups hold it) and the utensil ends in the bin."""
    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import noise_free, run_autonomous
    from dsteleop.robot.task import EventKind

    with KitchenEnv(noise_free(EnvConfig(description=load_description(robot)))) as env:
        for utensil in ("spoon", "spatula", "ladle"):
            result = run_autonomous(env, utensil, 0)
            kinds = [e.kind for e in result.events]
            assert EventKind.GRASP in kinds, (robot, utensil, result.outcome)
            assert result.outcome.success, (robot, utensil, result.outcome)


@pytest.mark.slow
def test_the_xarm_gripper_closes_on_the_grip_with_its_linkage_following() -> None:
    """The goal-seeking run to the spoon's grasp: when the task sees the grasp, the drive joint
    stands where the pads meet the 24 mm grip (0.65 rad by the URDF's geometry; 0 is open, 0.85
    the pads together), not closed through it, and every mimic joint of the linkage is at the
    drive's angle (multiplier 1), so both fingers' links touch the spoon."""
    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import goal_seeking_step, noise_free
    from dsteleop.robot.task import EventKind

    desc = load_description("xarm6")
    with KitchenEnv(noise_free(EnvConfig(description=desc))) as env:
        state = env.reset("spoon")
        X, task = state.palm, env.task
        for _ in range(round(10.0 / env.dt_s)):
            X_next = goal_seeking_step(X, task.goal, env.dt_s)
            env.set_target(X_next.position, X_next.rotation, X_next.openness)
            state = env.step()
            X = state.palm
            if any(e.kind == EventKind.GRASP for e in task.events):
                break
        else:
            pytest.fail("no grasp within 10 s")
        for _ in range(15):  # half a second held
            env.set_target(X.position, X.rotation, X.openness)
            state = env.step()
        q = state.joint_positions_rad
        assert 0.55 < q["drive_joint"] < 0.75, q["drive_joint"]
        for m in desc.mimic_joints:
            assert abs(q[m.name] - q["drive_joint"]) < 0.05, (m.name, q[m.name], q["drive_joint"])
        spoon = env.world.utensils["spoon"]
        touching = {c.robot_link for c in state.contacts if c.other_body == spoon}
        assert {"left_finger", "right_finger"} <= touching, touching


@pytest.mark.slow
def test_the_xarm_gripper_holds_the_spoon_commanded_just_past_the_pads_contact() -> None:
    """The goal-seeking run to the spoon's grasp with the openness stopped at 0.24 (the drive's
    command 0.646 rad, 0.016 rad past where the pads meet the 24 mm grip, about 0.63 rad), held
    1 s, then the palm lifted 10 cm: each pad presses the grip with over 1.5 N and the spoon
    comes up with it. Without the finger servo's integral (robot/arm.py, servo integral) the
    drive stood 0.014 rad short of its command, the pads pressed 0.4 N and the spoon stayed."""
    import numpy as np

    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import goal_seeking_step, noise_free

    g = np.array([0.24])
    with KitchenEnv(noise_free(EnvConfig(description=load_description("xarm6")))) as env:
        state = env.reset("spoon")
        X, task = state.palm, env.task
        for _ in range(round(10.0 / env.dt_s)):
            X_next = goal_seeking_step(X, task.goal, env.dt_s)
            env.set_target(X_next.position, X_next.rotation, np.maximum(X_next.openness, g))
            X = env.step().palm
            if X_next.openness[0] <= g[0]:
                break
        else:
            pytest.fail("the goal-seeking run did not close to 0.24 within 10 s")
        p0, R = X.position.copy(), X.rotation.copy()
        spoon = env.world.utensils["spoon"]
        for _ in range(round(1.0 / env.dt_s)):
            env.set_target(p0, R, g)
            state = env.step()
        press = {"left_finger": 0.0, "right_finger": 0.0}
        for c in state.contacts:
            if c.other_body == spoon and c.robot_link in press:
                press[c.robot_link] += c.normal_force_n
        assert min(press.values()) > 1.5, press
        z0 = env.utensil_pose("spoon")[0][2]
        for k in range(round(2.0 / env.dt_s)):
            env.set_target(p0 + np.array([0.0, 0.0, 0.10 * min(1.0, (k + 1) / 45)]), R, g)
            env.step()
        assert env.utensil_pose("spoon")[0][2] - z0 > 0.08


def test_the_so101_is_refused_for_the_kitchen_task() -> None:
    """The SO-101 loads (its URDF read as shipped, the jaw against the fixed jaw's group), but
    the kitchen's poses are out of its reach wherever the scene is moved: one line naming the
    first pose and the fix."""
    from dsteleop.robot.reach import require_reachable

    so101 = load_description("so101")
    assert so101.arm_joints[0] == "shoulder_pan" and len(so101.arm_joints) == 5
    assert dict(so101.link_groups) == {"gripper_link": "fixed"}
    with pytest.raises(InputError, match="is not reachable") as err:
        require_reachable(so101)
    assert "\n" not in str(err.value) and "so101.toml" in str(err.value)


def test_run_refuses_the_so101_in_one_line_exit_2(tmp_path: Path) -> None:
    """`dsteleop run --robot so101` refuses before anything runs or records: the task is out
    of the arm's reach (docs/robots.md)."""
    record = tmp_path / "session"
    r = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "run", "--source", "demo",
         "--robot", "so101", "--record", str(record)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "so101.toml" in lines[0] and "is not reachable" in lines[0]
    assert not record.exists()


@pytest.mark.parametrize(
    ("robot", "links"),
    [("ur5", ("upper_arm_link", "forearm_link", "palm")), ("xarm6", ("link3", "right_finger"))],
)
def test_the_page_draws_each_arm_from_its_meshes(
    robot: str, links: tuple[str, ...], caplog: pytest.LogCaptureFixture
) -> None:
    """`serve --robot ur5|xarm6`'s view: a real Viser server follows a live loop and draws the
    arm from its URDF's meshes (the UR5's visual meshes are COLLADA .dae files, read through
    pycollada, which the `robots` extra installs), with no error."""
    import time

    from dsteleop.app.compose import LoopOptions, build
    from dsteleop.app.loop.timing import ManualClock
    from dsteleop.app.viewer.server import Viewer, ViewerConfig
    from tests.deadlines import wait_for

    built = build(LoopOptions.of("demo", robot=robot), realtime=False, export_scene=True)
    loop = built.loop
    scene = loop.task.scene()
    assert scene is not None
    dae = [v for v in scene.visuals if str(v.mesh_path).endswith(".dae")]
    assert bool(dae) == (robot == "ur5")
    viewer = Viewer(loop.broadcaster, loop.controls, scene, ViewerConfig(port=0))
    try:
        viewer.start()
        clock = loop.clock
        assert isinstance(clock, ManualClock)
        for _ in range(30):
            loop.tick(clock.now())
            clock.advance(loop.config.dt_s)
            time.sleep(0.005)
        wait_for(lambda: viewer.stats.scene_updates >= 2)
        assert viewer.stats.errors == 0
        assert {f"robot/{name}" for name in links} <= set(viewer.scene.frames)
        unread = [r.getMessage() for r in caplog.records if "cannot be read" in r.getMessage()]
        assert not unread, unread[:2]  # every mesh drawn
    finally:
        viewer.close()
        built.close()
