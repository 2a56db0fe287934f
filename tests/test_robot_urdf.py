"""URDFs as users have them (docs/robots.md, issue 33): `<transmission>` blocks are not
joints, `<mimic>` joints follow their master's command within their limits, `package://` and
relative meshes resolve against a stated search path, every description field is
range-checked, and a bad inertia tensor is repaired and said once.

Every URDF here is built in a temporary folder from pybullet_data's Franka Panda (its
meshes linked, never copied), and run in real PyBullet."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pybullet_data
import pytest

from dsteleop.errors import InputError
from dsteleop.robot.description import RANGES, ROBOTS_DIR, load_description

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
PANDA_DIR = Path(pybullet_data.getDataPath()) / "franka_panda"
PANDA_URDF = (PANDA_DIR / "panda.urdf").read_text()
PANDA_TOML = (ROBOTS_DIR / "panda.toml").read_text()
ARM_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


def transmissions(names: list[str]) -> str:
    """ROS-style transmission blocks: a `<joint>` entry (no type) for each joint."""
    return "".join(
        f'<transmission name="{n}_tr"><type>transmission_interface/SimpleTransmission</type>'
        f'<joint name="{n}"><hardwareInterface>hardware_interface/PositionJointInterface'
        f'</hardwareInterface></joint><actuator name="{n}_motor"><mechanicalReduction>1'
        "</mechanicalReduction></actuator></transmission>\n"
        for n in names
    )


def workspace(tmp: Path) -> Path:
    """A ROS-like source folder: tmp/ws/src/my_panda/meshes (a link to pybullet_data's)."""
    pkg = tmp / "ws" / "src" / "my_panda"
    pkg.mkdir(parents=True, exist_ok=True)
    if not (pkg / "meshes").exists():
        (pkg / "meshes").symlink_to(PANDA_DIR / "meshes", target_is_directory=True)
    return tmp / "ws" / "src"


def make_robot(
    tmp: Path,
    urdf: str,
    toml_edit: Callable[[str], str] = lambda s: s,
    package_path: list[str] | None = None,
) -> Path:
    """tmp/robot/urdf/arm.urdf (`urdf`) and tmp/robot/arm.toml: the Panda's description
    pointing at it (edited by `toml_edit`), with `package_path` if given."""
    (tmp / "robot" / "urdf").mkdir(parents=True, exist_ok=True)
    (tmp / "robot" / "urdf" / "arm.urdf").write_text(urdf)
    text = PANDA_TOML.replace('"pybullet_data:franka_panda/panda.urdf"', '"urdf/arm.urdf"')
    if package_path is not None:
        text = f"package_path = {json.dumps(package_path)}\n" + text
    path = tmp / "robot" / "arm.toml"
    path.write_text(toml_edit(text))
    return path


def as_package(urdf: str, package: str = "my_panda") -> str:
    """pybullet_data's `package://meshes/...` (its own folder) as `package://PKG/meshes/...`."""
    return urdf.replace("package://meshes/", f"package://{package}/meshes/")


def with_transmissions(urdf: str, names: list[str]) -> str:
    return urdf.replace("</robot>", transmissions(names) + "</robot>")


# ------------------------------------------------------------------ transmissions


def test_a_urdf_with_transmissions_loads_and_its_chain_is_the_real_one(tmp_path: Path) -> None:
    """Before: the transmissions' `<joint>` entries replaced the real joints: "arm.joints:
    'panda_joint1' is None, not revolute"."""
    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.kinematics import ArmChain
    from dsteleop.robot.model import palm_tip_joints, robot_urdf_text

    urdf = with_transmissions(as_package(PANDA_URDF), [*ARM_JOINTS, "panda_finger_joint1"])
    workspace(tmp_path)
    desc = load_description(str(make_robot(tmp_path, urdf, package_path=["../ws/src"])))
    shipped = load_description("panda")
    assert desc.prismatic_joints == shipped.prismatic_joints
    chains = []
    for d in (desc, shipped):
        text = robot_urdf_text(d)
        chains.append(ArmChain.from_urdf(text, d.arm_joints, palm_tip_joints(d, text)))
    np.testing.assert_array_equal(chains[0].fixed, chains[1].fixed)
    np.testing.assert_array_equal(chains[0].lower_rad, chains[1].lower_rad)
    with KitchenEnv(EnvConfig(description=desc)) as env:
        state = env.reset("spoon")
        assert np.linalg.norm(state.palm.position - np.array(desc.home_position_m)) < 0.01


def test_a_joint_only_a_transmission_names_is_said_so(tmp_path: Path) -> None:
    urdf = with_transmissions(PANDA_URDF, ["panda_joint_ghost"])
    path = make_robot(
        tmp_path,
        urdf,
        lambda s: s.replace('"panda_joint7"]', '"panda_joint_ghost"]'),
        package_path=[str(PANDA_DIR)],
    )
    with pytest.raises(InputError) as err:
        load_description(str(path))
    msg = str(err.value)
    assert "arm.joints" in msg and "'panda_joint_ghost'" in msg and "<transmission>" in msg
    assert "\n" not in msg


# ------------------------------------------------------------------ mimic joints


def mimic_gripper(tmp: Path, multiplier: float, offset: float) -> Path:
    """The Panda with its second jaw a mimic (m, o) of the first; the description lists
    only the first jaw's joint and gives the second jaw's link its contact group."""
    urdf = PANDA_URDF.replace(
        '<mimic joint="panda_finger_joint1"/>',
        f'<mimic joint="panda_finger_joint1" multiplier="{multiplier}" offset="{offset}"/>',
    )
    assert urdf != PANDA_URDF

    def edit(s: str) -> str:
        jaw2 = '{ name = "panda_finger_joint2", open = 0.04, closed = 0.0, group = "right" }'
        s = s.replace(",\n          " + jaw2, "")
        return s.replace(
            'opposing = "left"', 'opposing = "left"\nlink_groups = { panda_rightfinger = "right" }'
        )

    path = make_robot(tmp, as_package(urdf), edit, package_path=["../ws/src"])
    workspace(tmp)
    return path


def free_air(env: Any, openness: float, ticks: int = 60) -> dict[str, float]:
    """Hold the palm at home with the gripper at `openness` for `ticks`: the joints after."""
    home = np.array(env.config.home_position_m)
    state = env.state()
    for _ in range(ticks):
        env.set_target(home, env.config.home_rotation, np.array([openness]))
        state = env.step()
    return dict(state.joint_positions_rad)


def test_a_mimic_jaw_follows_its_master_within_its_limits(tmp_path: Path) -> None:
    from dsteleop.robot.env import EnvConfig, KitchenEnv

    desc = load_description(str(mimic_gripper(tmp_path, 0.5, 0.01)))
    assert [j.name for j in desc.finger_joints] == ["panda_finger_joint1"]
    (mimic,) = desc.mimic_joints
    assert (mimic.name, mimic.master, mimic.multiplier, mimic.offset) == (
        "panda_finger_joint2",
        "panda_finger_joint1",
        0.5,
        0.01,
    )
    with KitchenEnv(EnvConfig(description=desc)) as env:
        env.reset("spoon")
        q = free_air(env, 1.0)
        assert q["panda_finger_joint1"] == pytest.approx(0.04, abs=1e-3)
        assert q["panda_finger_joint2"] == pytest.approx(0.5 * 0.04 + 0.01, abs=1e-3)
        q = free_air(env, 0.0)
        assert q["panda_finger_joint1"] == pytest.approx(0.0, abs=1e-3)
        assert q["panda_finger_joint2"] == pytest.approx(0.01, abs=1e-3)
        # both jaws are the right group's and the left's: the robot's clamp rule sees them
        assert env.robot.link_group == {"panda_leftfinger": "left", "panda_rightfinger": "right"}
    # an offset that would drive the mimic past its upper limit (0.04 + 0.03): held at 0.04
    desc = load_description(str(mimic_gripper(tmp_path / "b", 1.0, 0.03)))
    with KitchenEnv(EnvConfig(description=desc)) as env:
        env.reset("spoon")
        q = free_air(env, 1.0)
        assert q["panda_finger_joint2"] <= 0.04 + 1e-3
        assert q["panda_finger_joint2"] == pytest.approx(0.04, abs=1e-3)


def test_one_command_drives_a_mimic_gripper_through_the_task_within_its_limits(
    tmp_path: Path,
) -> None:
    """The goal-seeking run with the second jaw a mimic of the first (the description lists
    one joint) grasps the spoon and puts it in the bin; no jaw ever leaves its URDF limits."""
    from dsteleop.robot.env import EnvConfig, KitchenEnv
    from dsteleop.robot.scripted import goal_seeking_step, noise_free

    desc = load_description(str(mimic_gripper(tmp_path, 1.0, 0.0)))
    with KitchenEnv(noise_free(EnvConfig(description=desc))) as env:
        state = env.reset("spoon")
        X, worst = state.palm, 0.0
        while env.task.outcome is None:
            X_next = goal_seeking_step(X, env.task.goal, env.dt_s)
            env.set_target(X_next.position, X_next.rotation, X_next.openness)
            state = env.step()
            X = state.palm
            for n in ("panda_finger_joint1", "panda_finger_joint2"):
                q = state.joint_positions_rad[n]
                worst = max(worst, q - 0.04, -q)
        kinds = [e.kind.value for e in env.task.events]
        outcome = env.task.outcome
        assert outcome.success and outcome.reason == "in_bin", (outcome, kinds)
        assert "grasp" in kinds
    assert worst < 1e-3, f"a jaw went {worst * 1e3:.2f} mm past its URDF limit"


def test_a_finger_position_outside_its_urdf_limits_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "arm.toml"
    path.write_text(
        PANDA_TOML.replace(
            '"panda_finger_joint1", open = 0.04', '"panda_finger_joint1", open = 0.05'
        )
    )
    with pytest.raises(InputError, match=re.escape(
        "fingers[0].joints[0].open 0.05 is outside 'panda_finger_joint1''s URDF limits [0, 0.04]"
    )):  # fmt: skip
        load_description(str(path))
    path.write_text(PANDA_TOML.replace("[0.0, 0.2, 0.0, -2.0,", "[0.0, 0.2, 0.0, 0.5,"))
    with pytest.raises(InputError, match=re.escape("arm.rest_posture_rad[3] 0.5 is outside")):
        load_description(str(path))


# ------------------------------------------------------------------ mesh search path


def test_package_meshes_resolve_against_the_description_s_package_path(tmp_path: Path) -> None:
    from dsteleop.robot.bullet import pb
    from dsteleop.robot.model import load_robot, robot_urdf_text

    src = workspace(tmp_path)
    desc = load_description(
        str(make_robot(tmp_path, as_package(PANDA_URDF), package_path=["../ws/src"]))
    )
    assert desc.search_path()[0] == src.resolve()
    text = robot_urdf_text(desc)
    files = re.findall(r'filename="([^"]+)"', text)
    assert files and all(Path(f).is_absolute() and Path(f).is_file() for f in files)
    assert all(str(src.resolve() / "my_panda" / "meshes") in f for f in files)
    c = pb.connect(pb.DIRECT)
    try:
        loaded = load_robot(c, urdf_text=text)
        shapes = pb.getCollisionShapeData(
            loaded.body, loaded.links["panda_hand"], physicsClientId=c
        )
        assert shapes and shapes[0][4].decode().endswith("collision/hand.obj")
    finally:
        pb.disconnect(c)


@pytest.mark.parametrize("entry", ["src", "package"])
def test_ros_package_path_finds_the_meshes_as_ros_does(
    entry: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ROS_PACKAGE_PATH may list a folder of packages or a package itself."""
    src = workspace(tmp_path)
    path = make_robot(tmp_path, as_package(PANDA_URDF))
    with pytest.raises(InputError):
        monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
        monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
        load_description(str(path))
    folder = src if entry == "src" else src / "my_panda"
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"/nonexistent{os.pathsep}{folder}")
    assert load_description(str(path)).name == "panda"


def test_relative_meshes_resolve_beside_the_urdf_then_along_the_search_path(tmp_path: Path) -> None:
    urdf = PANDA_URDF.replace("package://meshes/", "meshes/")
    workspace(tmp_path)
    path = make_robot(tmp_path, urdf, package_path=["../ws/src/my_panda"])
    assert load_description(str(path)).name == "panda"


def test_a_missing_mesh_is_one_line_naming_it_and_the_search_path(tmp_path: Path) -> None:
    src = workspace(tmp_path)
    urdf = as_package(PANDA_URDF).replace("collision/hand.obj", "collision/hand_v2.obj")
    path = make_robot(tmp_path, urdf, package_path=["../ws/src"])
    with pytest.raises(InputError) as err:
        load_description(str(path))
    msg = str(err.value)
    assert "\n" not in msg and "'package://my_panda/meshes/collision/hand_v2.obj'" in msg
    assert str(src.resolve()) in msg and "package_path" in msg and "ROS_PACKAGE_PATH" in msg
    r = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "run", "--source", "demo",
         "--robot", str(path)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
        env={**os.environ, "ROS_PACKAGE_PATH": ""},
    )  # fmt: skip
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "hand_v2.obj" in lines[0], r.stderr


# ------------------------------------------------------------------ field ranges


def toml_text(data: dict[str, Any]) -> str:
    """A small TOML writer for descriptions (tables, arrays of tables, inline values)."""

    def val(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return "{ " + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + " }"

    lines, tables = [], []
    for k, v in data.items():
        if isinstance(v, dict):
            tables.append((f"[{k}]", v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables += [(f"[[{k}]]", x) for x in v]
        else:
            lines.append(f"{k} = {val(v)}")
    for head, table in tables:
        lines += [head, *(f"{k} = {val(x)}" for k, x in table.items())]
    return "\n".join(lines) + "\n"


def out_of_range(key: str) -> tuple[dict[str, Any], str]:
    """A description (as data) with `key` just above its range, and the field's name."""
    base = "iiwa" if key.startswith("mount.") else "panda"
    data = tomllib.loads((ROBOTS_DIR / f"{base}.toml").read_text())
    if base == "iiwa":
        data["mount"]["urdf"] = str((ROBOTS_DIR / data["mount"]["urdf"]).resolve())
    r = RANGES[key]
    bad = r.hi + 0.5 * abs(r.hi) + 0.1
    parts, at, name = key.split("."), data, []
    for p in parts[:-1]:
        at = at.setdefault(p, {}) if isinstance(at, dict) else at[p]  # [task]: optional
        name.append(p)
        if isinstance(at, list):  # fingers, joints: the first
            at = at[0]
            name[-1] += "[0]"
    leaf = parts[-1]
    old = at.get(leaf, [0.0, 0.0, 0.0] if leaf.endswith(("xyz_m", "rpy_rad")) else 0.0)
    at[leaf] = [bad, *old[1:]] if isinstance(old, list) else bad
    return data, ".".join([*name, leaf])


@pytest.mark.parametrize("key", sorted(RANGES))
def test_every_description_field_is_range_checked(key: str, tmp_path: Path) -> None:
    data, name = out_of_range(key)
    path = tmp_path / "arm.toml"
    path.write_text(toml_text(data))
    with pytest.raises(InputError) as err:
        load_description(str(path))
    msg = str(err.value)
    assert f"{name} must be in {RANGES[key]}" in msg and "\n" not in msg, msg


def test_the_shipped_descriptions_round_trip_through_the_test_writer(tmp_path: Path) -> None:
    for name in ("panda", "iiwa"):
        data = tomllib.loads((ROBOTS_DIR / f"{name}.toml").read_text())
        if "mount" in data:
            data["mount"]["urdf"] = str((ROBOTS_DIR / data["mount"]["urdf"]).resolve())
        path = tmp_path / f"{name}.toml"
        path.write_text(toml_text(data))
        assert tomllib.loads(path.read_text()) == data
        assert load_description(str(path)).name == name


def test_a_position_gain_above_one_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """At 2.0 PyBullet's position motor overshoots every step: the palm ended 0.42 m below
    the table."""
    path = tmp_path / "arm.toml"
    path.write_text(PANDA_TOML.replace("position_gain = 1.0", "position_gain = 2.0"))
    r = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "run", "--source", "demo",
         "--robot", str(path)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "arm.position_gain must be in (0, 1], got 2.0" in lines[0]


# ------------------------------------------------------------------ inertia


def test_a_bad_inertia_tensor_is_repaired_and_said_once_per_run(tmp_path: Path) -> None:
    """A link whose principal moments break the triangle inequality: PyBullet zeroes it and
    prints "Bad inertia tensor" at every load; here it is repaired before PyBullet sees it,
    one warning for the run (three resets), and none of PyBullet's."""
    at = PANDA_URDF.index('<link name="panda_leftfinger">')
    good = '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>'
    worse = '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>'
    bad = PANDA_URDF[:at] + PANDA_URDF[at:].replace(good, worse, 1)
    bad = bad.replace("package://meshes/", f"{PANDA_DIR}/meshes/")  # absolute: PyBullet's too
    assert bad != PANDA_URDF
    path = make_robot(tmp_path, bad)
    code = (
        "import logging, sys\n"
        "logging.basicConfig(level=logging.WARNING)\n"
        "from dsteleop.robot.description import load_description\n"
        "from dsteleop.robot.env import EnvConfig, KitchenEnv\n"
        "from dsteleop.robot.bullet import pb\n"
        f"desc = load_description({str(path)!r})\n"
        "for _ in range(2):\n"
        "    with KitchenEnv(EnvConfig(description=desc)) as env:\n"
        "        env.reset('spoon'); env.reset('ladle')\n"
        "        m = pb.getDynamicsInfo(env.robot.body, env.robot._r.links['panda_leftfinger'],"
        " physicsClientId=env.client)[2]\n"
        "        print('inertia', *m, flush=True)\n"
    )
    raw = (
        "from dsteleop.robot.bullet import pb\n"
        "c = pb.connect(pb.DIRECT)\n"
        f"pb.loadURDF({str(path.parent / 'urdf' / 'arm.urdf')!r}, useFixedBase=True,"
        " flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c)\n"
    )
    runs = [
        subprocess.run(
            [sys.executable, "-c", c], cwd=REPO, capture_output=True, text=True, timeout=180
        )
        for c in (code, raw)
    ]
    assert all(r.returncode == 0 for r in runs), [r.stderr for r in runs]
    ours, pybullets = (r.stdout + r.stderr for r in runs)  # PyBullet warns on stdout
    assert "Bad inertia tensor" in pybullets  # the URDF is really bad
    assert "Bad inertia tensor" not in ours, ours
    said = [ln for ln in ours.splitlines() if "moments of inertia" in ln]
    assert len(said) == 1 and "panda_leftfinger" in said[0], ours
    moments = [
        float(v)
        for ln in runs[0].stdout.splitlines()
        if ln.startswith("inertia")
        for v in ln.split()[1:]
    ]
    assert len(moments) == 6 and all(m > 0 for m in moments)
    a, b, c = sorted(moments[:3])
    assert c <= a + b + 1e-9 and math.isclose(c, 0.1)


def test_docs_give_every_range() -> None:
    """docs/robots.md's range table has a row for every field of `RANGES`, with its range."""
    rows = [
        ln for ln in (REPO / "docs" / "robots.md").read_text().splitlines() if ln.startswith("| `")
    ]
    for key, r in RANGES.items():
        assert any(f"`{key}`" in row and f"| {r} |" in row for row in rows), key
