"""Sessions as LeRobot v3.0 datasets: the layout, a round trip through replay, a checker that
is not ours (lerobot-doctor in its own virtual environment), bad input, live recording."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pyarrow.parquet as pq  # type: ignore[import-untyped]
import pytest

from dsteleop.app.lerobot import layout
from dsteleop.app.lerobot.check import problems
from dsteleop.app.lerobot.reader import read_dataset
from dsteleop.app.replay.core import replay_session
from dsteleop.app.session.reader import Session, read_session
from dsteleop.arbitration import Mode
from dsteleop.errors import InputError

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = ROOT / "recordings"
SAMPLES = sorted(p for p in RECORDINGS.iterdir() if (p / "meta.json").is_file())
#: The independent checker, pinned: installed from PyPI into its own virtual environment.
DOCTOR = "lerobot-doctor==0.2.0"


def dsteleop(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def samples_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The three sample sessions (demo operator, no camera) exported."""
    out = tmp_path_factory.mktemp("ds") / "samples"
    r = dsteleop("export", str(RECORDINGS), "--to", "lerobot", "--out", str(out))
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["episodes"] == 3 and summary["camera"] is False
    return out


@pytest.fixture(scope="module")
def video_session(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A session recorded from a real video with its camera frames (--record-video)."""
    folder = tmp_path_factory.mktemp("cam") / "cam"
    video = shared_data / "videos" / "webcam_two_hands.mp4"
    r = dsteleop("run", "--source", f"video:{video}", "--record", str(folder), "--record-video")
    assert r.returncode == 0, r.stderr
    return folder


@pytest.fixture(scope="module")
def video_dataset(video_session: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ds") / "cam"
    r = dsteleop("export", str(video_session), "--to", "lerobot", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


def test_the_sample_sessions_export_to_the_v3_layout(samples_dataset: Path) -> None:
    assert problems(samples_dataset) == []
    info = json.loads((samples_dataset / layout.INFO).read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 30
    assert info["total_episodes"] == 3 and info["total_tasks"] == 1
    # LeRobot's keys only (it warns about others, and drops them when it rewrites the file).
    assert set(info) <= {
        "codebase_version", "fps", "features", "total_episodes", "total_frames", "total_tasks",
        "chunks_size", "data_files_size_in_mb", "video_files_size_in_mb", "data_path",
        "video_path", "robot_type", "splits",
    }  # fmt: skip
    assert json.loads((samples_dataset / layout.MARK).read_text())["layout"] == 2
    feats = info["features"]
    dims = ["x", "y", "z", "roll", "pitch", "yaw", "thumb", "index", "middle", "ring"]
    assert feats["observation.state"]["names"] == [
        *("x", "y", "z", "qx", "qy", "qz", "qw"),
        *dims[6:],
    ]
    assert feats["action"]["names"] == feats["observation.state"]["names"]
    for key in layout.PER_DIM:
        assert feats[key] == {"dtype": "float32", "shape": [10], "names": dims}
    # The frames against the sessions: state before each tick, the commanded X_next, alpha.
    data = pq.read_table(samples_dataset / "data/chunk-000/file-000.parquet")
    eps = pq.read_table(samples_dataset / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    for row, folder in zip(eps, SAMPLES, strict=True):
        s = read_session(folder)
        assert row["dsteleop/session"] == folder.name
        assert row["dsteleop/mode"] == s.mode.value
        outcome = s.episodes[0].outcome
        assert outcome is not None
        assert row["dsteleop/outcome"] == ("success" if outcome.success else "failure")
        lo, hi = row["dataset_from_index"], row["dataset_to_index"]
        assert hi - lo == len(s.records)
        rows = data.slice(lo, hi - lo)
        state = np.array(rows.column("observation.state").to_pylist())
        action = np.array(rows.column("action").to_pylist())
        alpha = np.array(rows.column("observation.alpha").to_pylist())
        X = [r.X_current for r in s.records]
        np.testing.assert_allclose(state[1:, :3], [x.position for x in X[:-1]], atol=1e-6)
        X0 = s.records[0].X_reset
        assert X0 is not None
        np.testing.assert_allclose(state[0, :3], X0.position, atol=1e-6)
        np.testing.assert_allclose(action[:, :3], [r.X_next.position for r in s.records], atol=1e-6)
        np.testing.assert_allclose(action[:, 7:], [r.X_next.openness for r in s.records], atol=1e-6)
        arb = np.array([r.step is not None for r in s.records])
        np.testing.assert_allclose(
            alpha[arb], [r.step.alpha for r in s.records if r.step is not None], atol=1e-6
        )
        # quaternions are unit (x, y, z, w)
        np.testing.assert_allclose(np.linalg.norm(state[:, 3:7], axis=1), 1.0, atol=1e-6)
    # A robot told its goal is certain of it: the spoon while it picks, the bin after.
    assert feats[layout.GOAL_BELIEF]["names"] == ["spoon", "spatula", "ladle", "bin"]
    belief = np.array(data.column(layout.GOAL_BELIEF).to_pylist())
    assert set(np.unique(belief)) <= {0.0, 1.0} and (belief.sum(1) == 1).all()
    assert belief[0].tolist() == [1, 0, 0, 0] and belief[-1].tolist() == [0, 0, 0, 1]
    assert (np.array(data.column(layout.GOAL_CONFIDENCE).to_pylist()) == 1).all()
    tasks = pq.read_table(samples_dataset / layout.TASKS)
    assert tasks.column("task").to_pylist() == ["pick up the spoon and put it in the bin"]
    stats = json.loads((samples_dataset / layout.STATS).read_text())
    n = info["total_frames"]
    assert stats["observation.state"]["count"] == [n]
    all_state = np.array(data.column("observation.state").to_pylist())
    np.testing.assert_allclose(stats["observation.state"]["mean"], all_state.mean(0), atol=1e-5)
    np.testing.assert_allclose(stats["observation.state"]["max"], all_state.max(0), atol=1e-6)


def test_statistics_are_lerobots() -> None:
    """Per episode as numpy computes them; over the dataset, the exact mean, std, min and
    max of all frames; the camera's from its histogram equal to the pixels' own."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(40, 3)), rng.normal(2.0, 3.0, size=(90, 3))
    sa, sb = layout.feature_stats(a), layout.feature_stats(b)
    np.testing.assert_allclose(sa["q10"], np.quantile(a, 0.10, axis=0))
    agg = layout.aggregate_stats([{"f": sa}, {"f": sb}])["f"]
    both = np.concatenate([a, b])
    for name, f in (("mean", np.mean), ("std", np.std), ("min", np.min), ("max", np.max)):
        np.testing.assert_allclose(agg[name], f(both, axis=0), rtol=1e-12, atol=1e-12)
    assert agg["count"].tolist() == [130]
    pixels = rng.integers(0, 256, size=(7, 13, 11, 3)).astype(np.uint8)
    cam = layout.image_stats(pixels)
    ref = layout.feature_stats(pixels.reshape(-1, 3) / 255.0)
    for name in ("min", "max", "mean", "std", "q01", "q50", "q99"):
        assert cam[name].shape == (3, 1, 1)
        np.testing.assert_allclose(cam[name].ravel(), ref[name], rtol=1e-12, atol=1e-12)
    assert cam["count"].tolist() == [7]


def test_the_layout_check_finds_what_is_broken(samples_dataset: Path, tmp_path: Path) -> None:
    """Our check can fail: a gap in the frames, a wrong dtype, a lost stats entry."""
    path = samples_dataset / "data/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    damaged = {
        "gap": table.filter(pa.array(np.arange(table.num_rows) != 5)),
        "dtype": table.set_column(
            table.column_names.index("index"), "index", table.column("index").cast(pa.int32())
        ),
    }
    for name, t in damaged.items():
        broken = tmp_path / name
        shutil.copytree(samples_dataset, broken)
        pq.write_table(t, broken / "data/chunk-000/file-000.parquet")
        assert problems(broken), name
    broken = tmp_path / "stats"
    shutil.copytree(samples_dataset, broken)
    stats = json.loads((broken / layout.STATS).read_text())
    del stats["action"]["q99"]
    (broken / layout.STATS).write_text(json.dumps(stats))
    assert any("action" in p for p in problems(broken))


@pytest.mark.slow
def test_replaying_the_dataset_gives_the_sessions_metrics(
    samples_dataset: Path, tmp_path: Path
) -> None:
    metrics = {}
    for name, source in (("sessions", RECORDINGS), ("dataset", samples_dataset)):
        r = dsteleop(
            "replay", str(source), "--modes", "S,DS", "--out", str(tmp_path / name),
            "--no-plots", "--workers", "1",
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        metrics[name] = json.loads((tmp_path / name / "metrics.json").read_text())
    a, b = metrics["sessions"]["episodes"], metrics["dataset"]["episodes"]
    assert [e["name"] for e in a] == [e["name"] for e in b] and len(a) == 3

    def leaves(x: Any, path: str = "") -> dict[str, Any]:
        if isinstance(x, dict):
            return {k: v for key, val in x.items() for k, v in leaves(val, f"{path}/{key}").items()}
        return {path: x}

    for ea, eb in zip(a, b, strict=True):
        la, lb = leaves(ea["modes"]), leaves(eb["modes"])
        assert la.keys() == lb.keys()
        for k, va in la.items():
            if isinstance(va, float):
                assert math.isclose(va, lb[k], rel_tol=0, abs_tol=1e-9), (ea["name"], k)
            else:
                assert va == lb[k], (ea["name"], k)
    # Per tick too, against the recorded robot: every arbitration quantity.
    ds = read_dataset(samples_dataset)
    for view, folder in zip(ds.sessions, SAMPLES, strict=True):
        s = read_session(folder)
        assert_replays_alike(s.of_episode(s.episodes[0]), view)


def assert_replays_alike(original: Session, view: Session) -> None:
    """Against the recorded robot, in S and DS, the dataset's view of an episode gives every
    arbitration quantity of the original episode's replay, per tick, within 1e-9."""
    for mode in (Mode.S, Mode.DS):
        ta = replay_session(original, mode, robot="recorded")
        tb = replay_session(view, mode, robot="recorded")
        for name in ("alpha", "P_human", "P_robot", "B", "U_out"):
            np.testing.assert_allclose(
                getattr(ta.step, name), getattr(tb.step, name), rtol=0, atol=1e-9
            )


def test_episodes_counted_task_and_fps(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    r = dsteleop(
        "export", str(RECORDINGS / "demo-DS-spoon"), "--to", "lerobot", "--out", str(out),
        "--task", "put the spoon away", "--fps", "30", "--episodes", "counted", "--progress",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "export [" in r.stderr and "ticks" in r.stderr  # the progress bar, asked for
    assert json.loads(r.stdout)["episodes"] == 1
    assert problems(out) == []
    tasks = pq.read_table(out / layout.TASKS)
    assert tasks.column("task").to_pylist() == ["put the spoon away"]
    r = dsteleop(
        "export", str(RECORDINGS / "demo-DS-spoon"), "--to", "lerobot", "--out",
        str(tmp_path / "x"), "--fps", "15",
    )  # fmt: skip
    assert r.returncode == 2 and "30 Hz" in r.stderr
    assert not (tmp_path / "x").exists()


def _left_behind(parent: Path, name: str) -> list[str]:
    return [p.name for p in parent.iterdir() if p.name == name or p.name.startswith(f".{name}.")]


def test_bad_input_is_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    good = RECORDINGS / "demo-DS-spoon"
    corrupt = tmp_path / "corrupt"
    shutil.copytree(good, corrupt)
    lines = (corrupt / "ticks.jsonl").read_text().splitlines()
    lines[3] = lines[3][:20]
    (corrupt / "ticks.jsonl").write_text("\n".join(lines) + "\n")
    partial = tmp_path / "partial"
    shutil.copytree(good, partial)
    (partial / "meta.json").unlink()
    empty = tmp_path / "empty"
    shutil.copytree(good, empty)
    (empty / "ticks.jsonl").write_text("")
    full = tmp_path / "full"
    full.mkdir()
    (full / "something").write_text("x")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    out = tmp_path / "out"
    for args, needle in (
        ([str(corrupt), "--out", str(out)], "corrupt record"),
        ([str(partial), "--out", str(out)], "without its meta.json"),
        ([str(empty), "--out", str(out)], "empty session"),
        ([str(tmp_path / "nope"), "--out", str(out)], "not found"),
        ([str(good), "--out", str(full)], "not empty"),
        ([str(good), "--out", str(blocker / "ds")], "cannot write"),
    ):
        r = dsteleop("export", *args, "--to", "lerobot")
        assert r.returncode == 2, (needle, r.stderr)
        assert needle in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert r.stderr.strip().count("\n") == 0, r.stderr
        assert _left_behind(tmp_path, "out") == []
    assert [p.name for p in full.iterdir()] == ["something"]
    # The same folder for a live dataset: refused before anything is opened.
    r = dsteleop("run", "--source", "demo", "--record-lerobot", str(full))
    assert r.returncode == 2 and "not empty" in r.stderr, r.stderr
    assert r.stderr.strip().count("\n") == 0, r.stderr
    assert [p.name for p in full.iterdir()] == ["something"]


def test_a_dataset_that_is_not_ours_is_refused_by_replay(
    samples_dataset: Path, tmp_path: Path
) -> None:
    other = tmp_path / "other"
    shutil.copytree(samples_dataset, other)
    (other / layout.MARK).unlink()
    r = dsteleop("replay", str(other), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "did not write" in r.stderr
    assert r.stderr.strip().count("\n") == 0


@pytest.mark.slow
def test_a_real_video_session_exports_with_its_camera(
    video_session: Path, video_dataset: Path
) -> None:
    import av

    assert problems(video_dataset) == []
    info = json.loads((video_dataset / layout.INFO).read_text())
    # The iiwa's joints end the state (7 arm joints, 8 of its hand), named, one per column.
    session = read_session(video_session)
    names = info["features"]["observation.state"]["names"]
    assert len(session.joint_names) == 15 and session.joint_names[0] == "lbr_iiwa_joint_1"
    assert names[11:] == [f"joint.{n}" for n in session.joint_names]
    state = np.array(
        pq.read_table(video_dataset / "data/chunk-000/file-000.parquet")
        .column("observation.state")
        .to_pylist()
    )
    assert state.shape == (info["total_frames"], 26) and np.isfinite(state).all()
    cam = info["features"][layout.CAMERA]
    assert cam["dtype"] == "video" and cam["info"]["video.codec"] in ("av1", "h264")
    assert cam["info"]["video.g"] == 2 and cam["info"]["video.crf"] == 30
    stats = json.loads((video_dataset / layout.STATS).read_text())
    assert np.asarray(stats[layout.CAMERA]["mean"]).shape == (3, 1, 1)
    assert 0.0 < float(np.min(stats[layout.CAMERA]["mean"])) < 1.0
    # The video holds the session's frames: frame k of the dataset is the session's frame
    # that its tick showed (pixels alike after two lossy encodings).
    data = pq.read_table(video_dataset / "data/chunk-000/file-000.parquet")
    # The capture times since each episode's start, back on the loop's clock.
    eps = pq.read_table(video_dataset / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    starts = {int(r["episode_index"]): float(r[layout.T_START]) for r in eps}
    cam_t = data.column("dsteleop.camera_t_s").to_numpy() + np.array(
        [starts[int(e)] for e in data.column("episode_index").to_numpy()]
    )
    times = [json.loads(x)["t_capture"] for x in (video_session / "frames.jsonl").open()]
    with av.open(str(video_session / "video.mp4")) as c:
        original = [f.to_ndarray(format="gray") for f in c.decode(c.streams.video[0])]
    with av.open(str(next((video_dataset / "videos").rglob("*.mp4")))) as c:
        exported = [f.to_ndarray(format="gray") for f in c.decode(c.streams.video[0])]
    assert len(exported) == info["total_frames"]
    for k in range(0, len(exported), 17):
        i = int(np.argmin(np.abs(np.asarray(times) - cam_t[k])))
        assert abs(times[i] - cam_t[k]) < 1e-6, (k, times[i], cam_t[k])
        diff = np.abs(exported[k].astype(float) - original[i].astype(float)).mean()
        other = np.abs(exported[k].astype(float) - original[(i + 40) % len(original)]).mean()
        assert diff < 6.0 and diff < other, (k, diff, other)


def _doctor(cache: Path) -> Path:
    """lerobot-doctor in a virtual environment of its own (never dsteleop's), cached by
    version; skips only when the package registry cannot be reached."""
    venv = cache / f"venv-{DOCTOR.replace('==', '-')}-py{sys.version_info[0]}{sys.version_info[1]}"
    exe = venv / "bin" / "lerobot-doctor"
    if exe.is_file():
        return exe
    uv = shutil.which("uv") or str(ROOT / ".tools" / "bin" / "uv")
    if not Path(uv).is_file() and shutil.which(uv) is None:
        pytest.skip("uv is not installed (./dev.sh sync installs it)")
    env = {**os.environ, "UV_PYTHON_DOWNLOADS": "never"}
    env.pop("VIRTUAL_ENV", None)
    tmp = venv.with_name(venv.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    base = getattr(sys, "_base_executable", sys.executable)
    r = subprocess.run(
        [uv, "venv", "--quiet", "--python", base, str(tmp)],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = subprocess.run(
        [uv, "pip", "install", "--quiet", "--python", str(tmp / "bin" / "python"), DOCTOR],
        capture_output=True, text=True, env=env, timeout=900,
    )  # fmt: skip
    if r.returncode != 0:
        unreachable = ("dns", "connect", "network", "timed out", "resolve")
        if any(w in r.stderr.lower() for w in unreachable):
            pytest.skip(f"the package registry is unreachable: {r.stderr.strip()[-200:]}")
        raise AssertionError(r.stderr)
    shutil.rmtree(venv, ignore_errors=True)
    tmp.rename(venv)
    # The venv's scripts name the folder they were made in; call them through its python.
    return venv / "bin" / "python"


@pytest.mark.slow
def test_lerobot_doctor_accepts_an_exported_video_session(
    video_dataset: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "dsteleop-tests"
    cache.mkdir(parents=True, exist_ok=True)
    exe = _doctor(cache)
    py = exe.parent / "python"
    r = subprocess.run(
        [str(py), "-m", "lerobot_doctor.cli", str(video_dataset), "--json"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    report = json.loads(r.stdout)
    severities = {c["name"]: c["severity"] for c in report["checks"]}
    assert report["codebase_version"] == "v3.0" and report["total_episodes"] >= 1
    assert "FAIL" not in severities.values(), report
    # The format's checks pass; warnings, if any, are about the data itself (a hand lost
    # when the video ends freezes the actions; fingers held fully open sit at the limit).
    for name in ("Metadata & Format Compliance", "Temporal Consistency", "Video Integrity",
                 "Episode Health", "Training Readiness"):  # fmt: skip
        assert severities[name] == "PASS", (name, report)
    data_checks = {
        "Action Quality",
        "Data Distribution",
        "Anomaly Detection",
        "Per-Episode Summary",
    }
    assert {n for n, s in severities.items() if s == "WARN"} <= data_checks, severities
    assert len(severities) >= 10


RATE_HZ = 30.0
#: A child that records the demo with trials of 2 s, the task reset 0.5 s after each outcome,
#: into a live dataset, until it is killed.
LIVE_CHILD = """
import sys
from pathlib import Path
from dsteleop.app.compose import build
from dsteleop.app.compose import LoopOptions
from dsteleop.app.loop import LoopConfig
from dsteleop.arbitration import Mode

out = Path(sys.argv[1])
options = LoopOptions.of(
    "demo", LoopConfig(mode=Mode.DS, reset_after_s=0.5), time_limit_s=2.0, outputs={"lerobot": out}
)
built = build(options, realtime=False)
loop = built.loop
loop.start_recording(out / ".dsteleop-sessions" / "s")
for k in range(int(sys.argv[2])):
    loop.clock.sleep_until(k / 30.0)
    loop.tick(k / 30.0)
built.close()
"""


def test_a_robot_inferring_its_goal_records_its_belief_into_the_dataset(tmp_path: Path) -> None:
    """`run --goal infer --record-lerobot`: each frame carries the belief over the utensils
    (then the bin) and the confidence the session recorded; our check and our reader accept
    it, and the dataset's tick records read back with their belief."""
    out = tmp_path / "ds"
    r = dsteleop(
        "run", "--source", "demo", "--goal", "infer", "--utensil", "ladle", "--seed", "2",
        "--record-lerobot", str(out),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert problems(out) == []
    info = json.loads((out / layout.INFO).read_text())
    assert info["features"][layout.GOAL_BELIEF]["names"] == ["spoon", "spatula", "ladle", "bin"]
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    belief = np.array(data.column(layout.GOAL_BELIEF).to_pylist())
    conf = np.array(data.column(layout.GOAL_CONFIDENCE).to_pylist())
    joint = np.array(data.column(layout.GOAL_CONFIDENCE_JOINT).to_pylist())
    (view,) = read_dataset(out).sessions
    names = ["spoon", "spatula", "ladle", "bin"]
    assert len(view.records) == len(belief)
    for k, rec in enumerate(view.records):
        assert rec.belief is not None
        want = np.zeros(4)
        want[[names.index(n) for n in rec.belief.names]] = rec.belief.probability
        np.testing.assert_allclose(belief[k], want, atol=1e-6)
        np.testing.assert_allclose(conf[k], rec.belief.confidence, atol=1e-6)
        assert joint[k] == pytest.approx(rec.belief.confidence_joint, abs=1e-6)
    assert belief[:, :3].sum(1).max() == pytest.approx(1.0, abs=1e-6)  # the pick phase
    assert belief[-1].tolist() == [0, 0, 0, 1]  # the place phase: the bin
    assert (conf < 1).any()  # the utensils disagree along x, and the camera errs


def test_a_live_dataset_holds_every_episode_of_the_session(tmp_path: Path) -> None:
    out = tmp_path / "live"
    r = subprocess.run(
        [sys.executable, "-c", LIVE_CHILD, str(out), str(round(9.0 * RATE_HZ))],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert problems(out) == []
    session = read_session(out / ".dsteleop-sessions" / "s")
    ds = read_dataset(out)
    assert len(session.episodes) >= 3 and len(ds.sessions) == len(session.episodes)
    # Live, each episode in its own files; the same frames as an export of the session.
    assert len(list((out / "data").rglob("*.parquet"))) == len(session.episodes)
    exported = tmp_path / "exported"
    r = dsteleop("export", str(session.folder), "--to", "lerobot", "--out", str(exported))
    assert r.returncode == 0, r.stderr
    a = pq.read_table(out / "data/chunk-000/file-000.parquet")
    b = pq.read_table(exported / "data/chunk-000/file-000.parquet")
    b = b.slice(0, a.num_rows)
    for col in ("observation.state", "action", "observation.alpha", "index", "timestamp"):
        assert a.column(col).to_pylist() == b.column(col).to_pylist(), col
    for view, e in zip(ds.sessions, session.episodes, strict=True):
        assert view.episode is not None and view.episode.to_dict()["end"] == e.end
        assert len(view.records) == e.n_ticks


@pytest.mark.slow
def test_a_killed_live_recording_keeps_its_finished_episodes(tmp_path: Path) -> None:
    """kill -9 while the loop runs: the episodes that had ended are a valid dataset."""
    out = tmp_path / "live"
    proc = subprocess.Popen(
        [sys.executable, "-c", LIVE_CHILD, str(out), str(round(600 * RATE_HZ))],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            info = out / layout.INFO
            if info.is_file() and json.loads(info.read_text())["total_episodes"] >= 3:
                break
            time.sleep(0.05)
        else:
            pytest.fail("no three episodes were written")
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert problems(out) == []
    ds = read_dataset(out)
    assert len(ds.sessions) >= 3
    assert all(v.episode is not None and v.episode.end == "outcome" for v in ds.sessions)


def test_a_session_of_the_first_schema_exports_and_round_trips(tmp_path: Path) -> None:
    """Schema 1 (no reset states, outcomes without times): exported, and replayed from the
    dataset with the session's numbers."""
    golden = ROOT / "tests" / "golden" / "schema1-demo-DS-spoon"
    out = tmp_path / "ds"
    r = dsteleop("export", str(golden), "--to", "lerobot", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert problems(out) == []
    (view,) = read_dataset(out).sessions
    s = read_session(golden)
    a = replay_session(s.of_episode(s.episodes[0]), Mode.DS)
    b = replay_session(view, Mode.DS)
    for name in ("alpha", "B", "U_out"):
        np.testing.assert_allclose(getattr(a.step, name), getattr(b.step, name), rtol=0, atol=1e-9)
    assert a.outcome == b.outcome


# --- time columns that survive float32 (issue 33, item 10) -------------------------------

#: A loop clock after days of uptime (a monotonic clock counts from boot) [s]: float32 steps
#: by 0.0625 s there.
UPTIME_T0_S = 1_000_003.123456789
CAMERA_LEAD_S = 0.012  # each frame is captured this long before its tick


def _uptime_session(folder: Path, seconds: tuple[float, ...] = (3.0, 100.0)) -> list[float]:
    """A session of the loop (its own logic, fakes of the robot and task: no PyBullet) on a
    clock starting at `UPTIME_T0_S`, one episode per entry of `seconds` (the task reset in
    between), with a camera video beside it (`--record-video`'s files: a small synthetic
    H.264 and frames.jsonl, each frame captured `CAMERA_LEAD_S` before a tick). Returns the
    frames' capture times."""
    from dsteleop.app.loop import LoopConfig, TeleopLoop
    from dsteleop.app.loop.timing import ManualClock
    from dsteleop.app.session.video import FRAMES, VIDEO, Mp4Writer

    from .fakes import DT, ScriptedHand, fake_world, state

    start = state((0.5, 0.3, 0.4))
    loop = TeleopLoop(
        LoopConfig(mode=Mode.MANUAL),
        ScriptedHand(lambda t: start),
        *fake_world(start=start),
        clock=ManualClock(UPTIME_T0_S),
    )
    loop.start_recording(folder)
    k = 0
    for n, duration in enumerate(seconds):
        if n:
            loop.controls.reset()
        for _ in range(round(duration / DT)):
            t = UPTIME_T0_S + k * DT
            loop.clock.sleep_until(t)
            loop.tick(t)
            k += 1
    loop.close()
    times = [UPTIME_T0_S + i * DT - CAMERA_LEAD_S for i in range(k)]
    writer = Mp4Writer(folder / VIDEO, 30.0, 64, 48)
    try:
        with open(folder / FRAMES, "w", encoding="utf-8") as index:
            for i, t in enumerate(times):
                img = np.full((48, 64, 3), (7 * i) % 256, dtype=np.uint8)
                writer.write(img)
                index.write(json.dumps({"i": i, "seq": i, "t_capture": t}) + "\n")
    finally:
        writer.close()
    return times


class Uptime(NamedTuple):
    """`_uptime_session`'s session, its frames' capture times, and its export."""

    session: Path
    capture_t_s: list[float]
    dataset: Path


@pytest.fixture(scope="module")
def uptime(tmp_path_factory: pytest.TempPathFactory) -> Uptime:
    tmp = tmp_path_factory.mktemp("uptime")
    capture = _uptime_session(tmp / "s")
    r = dsteleop("export", str(tmp / "s"), "--to", "lerobot", "--out", str(tmp / "ds"))
    assert r.returncode == 0, r.stderr
    return Uptime(tmp / "s", capture, tmp / "ds")


def test_time_columns_count_from_the_episode_start_and_survive_float32(uptime: Uptime) -> None:
    """Written at a loop clock of ~1e6 s, the frame table's times read back within 1e-5 s of
    the true time since the episode's start through float32 (LeRobot's reader gives every
    float column to PyTorch as float32: the arrow cast below is the same rounding), and
    exactly through the project's reader, which adds each episode's start back."""
    from dsteleop.app.lerobot.reader import frame_times

    session, capture, out = read_session(uptime.session), uptime.capture_t_s, uptime.dataset
    assert problems(out) == []
    assert json.loads((out / layout.MARK).read_text())["layout"] == 2
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    eps = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [int(e["length"]) for e in eps] == [90, 3000]
    ep_col = data.column("episode_index").to_numpy()
    as_f32 = {
        k: data.column(k).cast(pa.float32()).to_numpy()
        for k in ("dsteleop.t_s", "dsteleop.camera_t_s")
    }
    dataset = read_dataset(out)
    assert dataset.layout == 2
    for e, (row, view) in enumerate(zip(eps, dataset.sessions, strict=True)):
        t_start = float(row[layout.T_START])
        records = session.of_episode(session.episodes[e]).records
        t_true = np.array([rec.t_s for rec in records])
        assert t_start == t_true[0] and t_start > UPTIME_T0_S - 1.0
        i0 = round((t_true[0] - UPTIME_T0_S) * 30)
        cam_true = np.array(capture[i0 : i0 + len(t_true)])
        m = ep_col == e
        # float64 in the file: the times since the start, to the last bits
        rel = data.column("dsteleop.t_s").to_numpy()[m]
        assert rel[0] == 0.0 and np.abs(rel - (t_true - t_start)).max() < 1e-9
        # float32, as LeRobot reads them: within 1e-5 s over a 100 s episode
        assert np.abs(as_f32["dsteleop.t_s"][m] - (t_true - t_start)).max() < 1e-5
        cam_err = np.abs(as_f32["dsteleop.camera_t_s"][m] - (cam_true - t_start)).max()
        assert cam_err < 1e-5, cam_err
        # ... where the loop's clock itself would have been off by up to 31 ms
        assert np.abs(t_true.astype(np.float32) - t_true).max() > 1e-2
        # the project's reader: the loop's times back (the start plus the columns), and the
        # tick records of a replay exactly as recorded
        times = frame_times(dataset, e)
        assert times.camera_t_s is not None
        assert np.abs(times.t_s - t_true).max() < 1e-6
        assert np.abs(times.camera_t_s - cam_true).max() < 1e-6
        assert [rec.t_s for rec in view.records] == list(t_true)


def test_the_layout_check_wants_the_time_columns_from_the_episode_start(
    uptime: Uptime, tmp_path: Path
) -> None:
    """The loop's clock itself in `dsteleop.t_s` (layout 1), or an episode table without the
    start, is found by our check."""
    bad = tmp_path / "bad"
    shutil.copytree(uptime.dataset, bad)
    path = bad / "data/chunk-000/file-000.parquet"
    t = pq.read_table(path)
    starts = {
        int(r["episode_index"]): float(r[layout.T_START])
        for r in pq.read_table(bad / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    }
    loop_clock = t.column("dsteleop.t_s").to_numpy() + np.array(
        [starts[int(e)] for e in t.column("episode_index").to_numpy()]
    )
    i = t.column_names.index("dsteleop.t_s")
    pq.write_table(t.set_column(i, "dsteleop.t_s", pa.array(loop_clock)), path)
    found = problems(bad)
    assert any("not 0" in p for p in found) and any(layout.T_START in p for p in found), found
    # ... which is what a dataset of layout 1 held: its reader takes the columns as they are.
    from dsteleop.app.lerobot.reader import frame_times

    mark = json.loads((bad / layout.MARK).read_text())
    (bad / layout.MARK).write_text(json.dumps({**mark, "layout": 1}))
    old = read_dataset(bad)
    assert old.layout == 1 and old.t_start_s(1) == 0.0
    m = t.column("episode_index").to_numpy() == 1
    assert np.array_equal(frame_times(old, 1).t_s, loop_clock[m])
    (bad / layout.MARK).write_text(json.dumps({**mark, "layout": 3}))
    with pytest.raises(InputError, match="layout 3; this version reads layouts 1 to 2"):
        read_dataset(bad)
    (bad / layout.MARK).write_text(json.dumps(mark))
    eps_path = bad / "meta/episodes/chunk-000/file-000.parquet"
    eps = pq.read_table(eps_path)
    pq.write_table(eps.drop_columns([layout.T_START]), eps_path)
    assert any(f"no {layout.T_START}" in p for p in problems(bad)), problems(bad)


def test_lerobot_itself_reads_the_times_since_the_episode_start(tmp_path: Path) -> None:
    """With LeRobot installed (optional: it needs PyTorch), its own reader gives the times
    within 1e-5 s of the true time since each episode's start, at a loop clock of ~1e6 s."""
    lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset")

    session_dir = tmp_path / "s"
    _uptime_session(session_dir, (3.0, 20.0))
    out = tmp_path / "ds"
    r = dsteleop("export", str(session_dir), "--to", "lerobot", "--out", str(out))
    assert r.returncode == 0, r.stderr
    session = read_session(session_dir)
    ds = lerobot_dataset.LeRobotDataset("dsteleop/uptime", root=str(out))
    starts = list(ds.meta.episodes[layout.T_START])
    t_true = [rec.t_s for ep in session.episodes for rec in session.of_episode(ep).records]
    for k in range(0, len(ds), 37):
        frame = ds[k]
        e = int(frame["episode_index"])
        got = float(frame["dsteleop.t_s"])
        assert abs(got - (t_true[k] - starts[e])) < 1e-5, (k, got)
