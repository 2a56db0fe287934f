"""The robot's joint positions in sessions (schema 4) and in LeRobot datasets: recorded each
tick from real PyBullet robots (the iiwa with its hand, the Panda with its gripper), played
back by the recorded robot, exported into `observation.state`, and refused where sessions do
not share one robot's joints."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq  # type: ignore[import-untyped]
import pytest

from dsteleop.app.jsonable import jsonable
from dsteleop.app.lerobot import layout
from dsteleop.app.lerobot.check import problems
from dsteleop.app.lerobot.reader import read_dataset
from dsteleop.app.plants.described import joint_names_of
from dsteleop.app.plants.recorded import recorded_pair
from dsteleop.app.replay.core import replay_session
from dsteleop.app.session.reader import Session, read_session
from dsteleop.app.session.schema import SCHEMA, TickRecord, decode, encode
from dsteleop.app.session.writer import META, TICKS
from dsteleop.arbitration import Mode
from dsteleop.robot.description import description_from_record, load_description
from dsteleop.robot.kinematics import ArmChain
from dsteleop.robot.model import palm_tip_joints, robot_urdf_text
from dsteleop.robot.scene import SceneGeometry
from tests.test_lerobot import _doctor, assert_replays_alike
from tests.test_session_schema import full_record, lost_record

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"
#: The robots' joints: (arm joints, finger joints, which of them are prismatic).
ROBOTS = {"iiwa": (7, 8, ()), "panda": (7, 2, ("panda_finger_joint1", "panda_finger_joint2"))}


def dsteleop(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=600)


def one_line_refusal(r: subprocess.CompletedProcess[str], needle: str) -> None:
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().count("\n") == 0, r.stderr


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A demo session of each robot, recorded by `dsteleop run` (one episode each)."""
    root = tmp_path_factory.mktemp("joints")
    out = {}
    for robot in ROBOTS:
        folder = root / robot
        r = dsteleop("run", "--source", "demo", "--robot", robot, "--record", str(folder))
        assert r.returncode == 0, r.stderr
        out[robot] = folder
    return out


# --- the record --------------------------------------------------------------------------------


def test_joints_round_trip_through_json_at_full_precision() -> None:
    rng = np.random.default_rng(3)
    r = full_record(4)
    q, q0 = rng.normal(size=15), rng.normal(size=15)
    q[3] = np.nan  # a joint the robot did not report: null in JSON, NaN again
    r = dataclasses.replace(r, plant=dataclasses.replace(r.plant, joints=q), joints_reset=q0)
    # As the session writer writes it (NaN as null: JSON has none).
    d = json.loads(json.dumps(jsonable(encode(r)), allow_nan=False))
    assert d["joints"][3] is None and len(d["joints"]) == 15 and d["joints_reset"] == q0.tolist()
    back = decode(d, r.dims)
    assert back.plant.joints is not None and back.joints_reset is not None
    np.testing.assert_array_equal(back.plant.joints, q)  # NaN where NaN, every bit elsewhere
    np.testing.assert_array_equal(back.joints_reset, q0)
    # joints_reset only beside X_reset; a record without joints writes neither key, as
    # schema 3 did, and reads back without them.
    no_reset = dataclasses.replace(r, X_reset=None)
    assert "joints" in encode(no_reset) and "joints_reset" not in encode(no_reset)
    for plain in (full_record(5), lost_record()):
        d = encode(plain)
        assert "joints" not in d and "joints_reset" not in d
        back = decode(json.loads(json.dumps(d)), plain.dims)
        assert back.plant.joints is None and back.joints_reset is None


def test_a_schema_3_session_reads_back_without_joints_and_plays_back_without_them() -> None:
    s = read_session(RECORDINGS / "demo-DS-spoon")
    assert s.meta["schema"] == "dsteleop.session/3" != SCHEMA
    assert s.joint_names == () and s.joint_units == ()
    assert all(r.plant.joints is None and r.joints_reset is None for r in s.records)
    robot, _ = recorded_pair(s)
    assert robot.joint_names == () and robot.reset(0.0).joints.shape == (0,)
    st = robot.state(0.0)
    assert st is not None and st.joints.shape == (0,)


# --- a real recording ----------------------------------------------------------------------------


def _chain(s: Session) -> ArmChain:
    """The arm of the session's robot, from its recorded description (forward kinematics)."""
    desc = description_from_record(s.meta["robot"])
    text = robot_urdf_text(desc)
    return ArmChain.from_urdf(text, desc.arm_joints, palm_tip_joints(desc, text))


@pytest.mark.slow
@pytest.mark.parametrize("robot", list(ROBOTS))
def test_a_recording_holds_the_robots_joints_each_tick(
    recorded: dict[str, Path], robot: str
) -> None:
    s = read_session(recorded[robot])
    n_arm, n_finger, prismatic = ROBOTS[robot]
    desc = load_description(robot)
    assert s.meta["schema"] == SCHEMA
    assert s.joint_names == joint_names_of(desc) and len(s.joint_names) == n_arm + n_finger
    assert s.joint_names[:n_arm] == desc.arm_joints
    units = dict(zip(s.joint_names, s.joint_units, strict=True))
    assert units == {n: "m" if n in prismatic else "rad" for n in s.joint_names}
    assert s.records[0].joints_reset is not None
    assert all(r.joints_reset is None for r in s.records[1:])
    q = np.array([r.plant.joints for r in s.records])
    assert q.shape == (len(s.records), n_arm + n_finger) and np.isfinite(q).all()
    # The joints are those of the palm pose of the same tick: the arm's forward kinematics
    # of tick k's joints is tick k's palm to a micrometre (the palm moves up to 8 mm a tick,
    # so a joint vector one tick off would miss by millimetres).
    chain = _chain(s)
    for k, r in enumerate(s.records):
        p, R = chain.fk(q[k, :n_arm])
        assert np.linalg.norm(p - r.X_current.position) < 1e-5, k
        assert np.abs(R - r.X_current.rotation).max() < 1e-4, k
    X0, q0 = s.records[0].X_reset, s.records[0].joints_reset
    assert X0 is not None and q0 is not None
    assert np.linalg.norm(chain.fk(q0[:n_arm])[0] - X0.position) < 1e-5
    # The arm went somewhere (a pick and place), and the fingers closed on the utensil.
    assert np.ptp(q[:, :n_arm], axis=0).max() > 0.2
    assert np.ptp(q[:, n_arm:], axis=0).max() > (0.005 if prismatic else 0.1)
    if prismatic:  # the Panda's jaws, in metres: within their 0..0.04 m stroke
        assert q[:, n_arm:].min() > -1e-3 and q[:, n_arm:].max() < 0.041


@pytest.mark.slow
def test_replay_against_the_recorded_robot_returns_the_recorded_joints(
    recorded: dict[str, Path],
) -> None:
    s = read_session(recorded["panda"])
    view = s.of_episode(s.episodes[0])
    got: list[Sequence[TickRecord]] = []

    def sink(records: Sequence[TickRecord], scene: SceneGeometry | None) -> None:
        got.append(records)

    replay_session(view, Mode.S, robot="recorded", sink=sink)
    (records,) = got
    assert len(records) == len(view.records)
    for a, b in zip(view.records, records, strict=True):
        assert a.plant.joints is not None and b.plant.joints is not None
        np.testing.assert_array_equal(a.plant.joints, b.plant.joints)
    assert records[0].joints_reset is not None and view.records[0].joints_reset is not None
    np.testing.assert_array_equal(records[0].joints_reset, view.records[0].joints_reset)
    # What the recorded robot reports through the port, directly.
    robot, task = recorded_pair(view)
    assert robot.joint_names == s.joint_names and robot.joint_units == s.joint_units
    np.testing.assert_array_equal(robot.reset(0.0).joints, view.records[0].joints_reset)
    for k in range(3):
        st = robot.state(0.0)
        assert st is not None
        np.testing.assert_array_equal(st.joints, view.records[k].plant.joints)
        task.update(st)


# --- the LeRobot dataset ------------------------------------------------------------------------


def _state_and_action(ds: Path) -> tuple[dict[str, object], np.ndarray, np.ndarray]:
    info = json.loads((ds / layout.INFO).read_text())
    data = pq.read_table(ds / "data/chunk-000/file-000.parquet")
    state = np.array(data.column("observation.state").to_pylist())
    action = np.array(data.column("action").to_pylist())
    return info, state, action


@pytest.mark.slow
@pytest.mark.parametrize("robot", list(ROBOTS))
def test_the_export_puts_the_joints_into_the_state_and_round_trips(
    recorded: dict[str, Path], robot: str, tmp_path: Path
) -> None:
    out = tmp_path / "ds"
    r = dsteleop("export", str(recorded[robot]), "--to", "lerobot", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert problems(out) == []
    s = read_session(recorded[robot])
    F = len(s.dims) - 6
    J = len(s.joint_names)
    info, state, action = _state_and_action(out)
    feats = info["features"]
    assert isinstance(feats, dict)
    names = feats["observation.state"]["names"]
    assert names[: 7 + F] == [*layout.POSE_NAMES, *s.dims[6:]]
    assert names[7 + F :] == [f"joint.{n}" for n in s.joint_names]
    assert feats["observation.state"]["shape"] == [7 + F + J] and state.shape[1] == 7 + F + J
    assert feats["action"]["names"] == names[: 7 + F] and action.shape[1] == 7 + F
    assert info["robot_type"] == robot
    # The joints when each tick started: at the reset, then the previous tick's.
    q0 = s.records[0].joints_reset
    assert q0 is not None
    q = np.array([q0, *(r.plant.joints for r in s.records[:-1])], dtype=np.float32)
    np.testing.assert_array_equal(state[:, 7 + F :], q)
    stats = json.loads((out / layout.STATS).read_text())["observation.state"]
    assert len(stats["mean"]) == 7 + F + J
    np.testing.assert_allclose(stats["max"][7 + F :], q.max(axis=0), rtol=0, atol=1e-6)
    # Round trip: the dataset replays to the session's numbers, and its recorded robot
    # reports the session's joints.
    (view,) = read_dataset(out).sessions
    assert view.joint_names == s.joint_names and view.joint_units == s.joint_units
    original = s.of_episode(s.episodes[0])
    assert_replays_alike(original, view)
    for a, b in zip(original.records, view.records, strict=True):
        assert a.plant.joints is not None and b.plant.joints is not None
        np.testing.assert_array_equal(a.plant.joints, b.plant.joints)


@pytest.mark.slow
def test_sessions_without_one_robots_joints_are_refused_in_one_line(
    recorded: dict[str, Path], tmp_path: Path
) -> None:
    iiwa = recorded["iiwa"]
    out = tmp_path / "out"
    # With and without joint positions (a session of schema 3), either way round.
    for pair in ((iiwa, RECORDINGS / "demo-DS-spoon"), (RECORDINGS / "demo-S-spoon", iiwa)):
        r = dsteleop("export", *map(str, pair), "--to", "lerobot", "--out", str(out))
        one_line_refusal(r, "joint positions")
        assert not out.exists()
    # Another robot's joints behind the same dimensions (the names are what differs).
    other = tmp_path / "other"
    shutil.copytree(iiwa, other)
    meta = json.loads((other / META).read_text())
    meta["joint_names"] = [f"other_{n}" for n in meta["joint_names"]]
    (other / META).write_text(json.dumps(meta))
    r = dsteleop("export", str(iiwa), str(other), "--to", "lerobot", "--out", str(out))
    one_line_refusal(r, "different robots")
    # Another robot's name behind the same dimensions and joints (info.json's robot_type).
    renamed = tmp_path / "renamed"
    shutil.copytree(iiwa, renamed)
    meta = json.loads((renamed / META).read_text())
    meta["robot"]["name"] = "iiwa_copy"
    (renamed / META).write_text(json.dumps(meta))
    r = dsteleop("export", str(iiwa), str(renamed), "--to", "lerobot", "--out", str(out))
    one_line_refusal(r, "its robot (iiwa_copy) differs")
    # Different robots (the Panda's one finger against the iiwa's four).
    r = dsteleop("export", str(iiwa), str(recorded["panda"]), "--to", "lerobot", "--out", str(out))
    one_line_refusal(r, "dimensions")
    # A session that names joints but whose tick lacks them (edited by hand).
    holed = tmp_path / "holed"
    shutil.copytree(iiwa, holed)
    lines = (holed / TICKS).read_text().splitlines()
    d = json.loads(lines[5])
    del d["joints"]
    lines[5] = json.dumps(d)
    (holed / TICKS).write_text("\n".join(lines) + "\n")
    r = dsteleop("export", str(holed), "--to", "lerobot", "--out", str(out))
    one_line_refusal(r, "joint positions")
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith((".out", "out"))] == []


@pytest.mark.slow
def test_a_live_dataset_of_the_panda_has_its_joints(tmp_path: Path) -> None:
    """`--record-lerobot`: the episode, written as it ends, with the Panda's joints, the
    same frames as an export of the session it was written from."""
    live = tmp_path / "live"
    r = dsteleop("run", "--source", "demo", "--robot", "panda", "--record-lerobot", str(live))
    assert r.returncode == 0, r.stderr
    assert problems(live) == []
    (session,) = (live / ".dsteleop-sessions").iterdir()
    exported = tmp_path / "exported"
    r = dsteleop("export", str(session), "--to", "lerobot", "--out", str(exported))
    assert r.returncode == 0, r.stderr
    info, state, _ = _state_and_action(live)
    _, state_exported, _ = _state_and_action(exported)
    names = info["features"]["observation.state"]["names"]  # type: ignore[index]
    assert names[8:] == [f"joint.{n}" for n in joint_names_of(load_description("panda"))]
    assert state.shape[1] == 17
    np.testing.assert_array_equal(state, state_exported)


@pytest.mark.slow
def test_lerobot_doctor_accepts_the_pandas_joints(
    recorded: dict[str, Path], tmp_path: Path
) -> None:
    """The Panda's dataset (one finger, two prismatic jaws among its joints, no camera) by
    the checker that is not ours, in its own virtual environment (`test_lerobot._doctor`)."""
    out = tmp_path / "ds"
    r = dsteleop("export", str(recorded["panda"]), "--to", "lerobot", "--out", str(out))
    assert r.returncode == 0, r.stderr
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "dsteleop-tests"
    cache.mkdir(parents=True, exist_ok=True)
    py = _doctor(cache).parent / "python"
    r = subprocess.run(
        [str(py), "-m", "lerobot_doctor.cli", str(out), "--json"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    report = json.loads(r.stdout)
    severities = {c["name"]: c["severity"] for c in report["checks"]}
    assert "FAIL" not in severities.values(), report
    # The format's checks pass (warnings, if any, are about the data: no camera, a jump of
    # the robot policy's action at the grasp).
    for name in ("Metadata & Format Compliance", "Feature Consistency", "Temporal Consistency",
                 "Episode Health"):  # fmt: skip
        assert severities[name] == "PASS", (name, report)
