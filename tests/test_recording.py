"""Session recording and headless replay: round trips, crashes, bad files, real videos."""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.loop import LoopConfig
from dsteleop.app.replay.core import as_recorded, replay_session
from dsteleop.app.session.reader import Session, read_session
from dsteleop.app.session.schema import READABLE, SCHEMA
from dsteleop.app.session.writer import HISTORY_FILE, TICKS
from dsteleop.arbitration import STEP_ARRAYS, Mode, OperatorHistory
from dsteleop.robot.task import EventKind

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"


def recorded_alphas(s: Session) -> NDArray[np.float64]:
    """(arbitrated ticks, D) the alphas the session recorded."""
    return np.array([r.step.alpha for r in s.records if r.step is not None])


@pytest.fixture(scope="module")
def ds_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One DS session recorded from the demo operator (headless)."""
    root = tmp_path_factory.mktemp("sessions")
    folder = root / "demo-ds"
    built = build(
        LoopOptions.of("demo", LoopConfig(mode=Mode.DS), history=root / HISTORY_FILE),
        realtime=False,
    )
    try:
        built.loop.start_recording(folder)
        # Until an outcome: the task's own timeout (120 s) ends a stuck run as a failure, so
        # the session always has one, whatever this machine's physics does with the grasp.
        built.loop.run_headless(max_ticks=3700)
    finally:
        built.loop.close()
    return folder


def _outcome(meta: dict[str, Any]) -> str:
    """The recorded outcome of a one-episode session: "success", "failure" or "none"."""
    o = meta["episodes"][0]["outcome"] if meta.get("episodes") else meta.get("outcome")
    if isinstance(o, dict):
        return "success" if o["success"] else "failure"
    return str(o or "none")


def test_session_files_and_metadata(ds_session: Path) -> None:
    s = read_session(ds_session)
    assert s.complete and not s.truncated
    meta = s.meta
    assert meta["schema"] == SCHEMA == "dsteleop.session/5"
    assert meta["loop"]["arbitration"]["kappa"] == 4.0
    assert meta["mode"] == "DS" and meta["dims"][:6] == ["x", "y", "z", "roll", "pitch", "yaw"]
    assert s.mode is Mode.DS and s.dims == tuple(meta["dims"])
    assert meta["plant"]["utensil"] == "spoon" and "pick_known" in meta["plant"]
    assert meta["n_ticks"] == len(s.records) > 100
    # One episode, reset to outcome, in the metadata (written as it ended).
    (episode,) = meta["episodes"]
    assert meta["n_episodes"] == 1 and episode["end"] == "outcome"
    assert episode["first_tick"] == 0 and episode["last_tick"] == len(s.records) - 1
    assert episode["outcome"]["success"] in (True, False) and episode["duration_s"] > 3
    assert [e.to_dict() for e in s.episodes] == meta["episodes"]
    # The file format: every key of a tick line (recordings/README.md).
    lines = (ds_session / TICKS).read_text().splitlines()
    first = json.loads(lines[0])
    for key in (
        "k",
        "t",
        "mode",
        "status",
        "reason",
        "phase",
        "outcome",
        "hand",
        "X_current",
        "X_goal",
        "X_next",
        "U_cmd",
        "arb",
        "timing",
        "events",
        "notes",
        "X_reset",  # the first tick carries the state the task reset to
    ):
        assert key in first
    arb = next(d["arb"] for d in map(json.loads, lines) if d["arb"])
    for key in STEP_ARRAYS:
        assert len(arb[key]) == len(meta["dims"])
    # The same, read back typed.
    step = next(r.step for r in s.records if r.step is not None)
    for key in STEP_ARRAYS:
        assert getattr(step, key).shape == (len(meta["dims"]),)
    events = [e for r in s.records for e in r.plant.events]
    outcome = next(r.outcome for r in s.records if r.outcome is not None)
    assert outcome.success == meta["episodes"][0]["outcome"]["success"]
    # The operator history persisted beside the session: one attempt per finished segment
    # (the pick ends at the grasp, the place at the outcome; a run that never grasps ends
    # its one segment at the outcome). Whether this machine's physics grasps is not tested
    # here (tests/test_demo.py tests the demo's outcomes as rates over seeds).
    hist = OperatorHistory.from_dict(json.loads((ds_session.parent / HISTORY_FILE).read_text()))
    grasps = sum(e.kind is EventKind.GRASP for e in events)
    assert len(hist) == grasps + 1


def test_replay_in_the_recorded_mode_reproduces_every_alpha(ds_session: Path) -> None:
    s = read_session(ds_session)
    recorded = recorded_alphas(s)
    # Against the recorded robot (open loop, no physics): the same inputs, the same alphas.
    trace = replay_session(s, Mode.DS, robot="recorded")
    np.testing.assert_allclose(trace.step.alpha[trace.arbitrated], recorded, atol=1e-9, rtol=0)
    assert trace.outcome_name == _outcome(s.meta)
    again = as_recorded(s)
    np.testing.assert_allclose(again.step.alpha[again.arbitrated], recorded, atol=0, rtol=0)
    # Against a fresh simulated robot (closed loop): the same world and hand; contacts may
    # part ways in the last bits, so only the free-space reach is compared, to 1 mm.
    sim = replay_session(s, Mode.DS)
    p_rec = np.array([r.X_current.position for r in s.records])
    early = sim.t_s < 2.0
    assert early.sum() > 30
    np.testing.assert_allclose(sim.p_robot[early], p_rec[early], atol=1e-3)


def test_replay_command_writes_complete_metrics(ds_session: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = subprocess.run(
        [*CLI, "replay", str(ds_session), "--modes", "S,DS,manual", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["wall_s"] > 0
    (sess,) = m["episodes"]
    assert sess["name"] == f"{ds_session.name}/ep0" and sess["duration_s"] > 3
    assert sess["session"] == ds_session.name and sess["counted"] and sess["end"] == "outcome"
    for mode in ("S", "DS", "manual"):
        row = sess["modes"][mode]
        for key in ("success", "time_s", "cosine_distance", "agreement", "mean_alpha"):
            assert key in row
        assert set(row["mean_alpha"]) >= {"x", "y", "z", "roll", "pitch", "yaw"}
        assert m["modes"][mode]["n"] == 1
    assert sess["modes"]["manual"]["cosine_distance"] == pytest.approx(0.0, abs=1e-9)
    assert sess["modes"]["manual"]["agreement"] == 1.0
    # Fig. 8's pairs of divergences, each in [0, 1]; manual's robot is its hand.
    div = m["divergence"]
    assert set(div["fig8"]) == {
        "operator_DS~operator_S",
        "robot_DS~robot_S",
        "operator_DS~robot_DS",
        "operator_S~robot_S",
    }
    assert all(0.0 <= v <= 1.0 for v in div["fig8"].values())
    assert div["operator_vs_robot"]["manual"] < div["operator_vs_robot"]["S"]
    assert "success_mcnemar" in m["tests"]["S_vs_DS"]
    # One episode a mode: the tests are reported, with their n, as not meaningful.
    assert m["tests"]["S_vs_DS"]["n"] == [1, 1] and not m["tests"]["S_vs_DS"]["meaningful"]
    assert "not meaningful" in r.stderr
    assert sorted(p.name for p in out.glob("*.png"))  # plots were written


def test_a_truncated_last_record_is_skipped_with_a_warning(
    ds_session: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    copy = tmp_path / "cut"
    shutil.copytree(ds_session, copy)
    ticks = copy / "ticks.jsonl"
    data = ticks.read_bytes()
    n = data.count(b"\n")
    ticks.write_bytes(data + data.splitlines(keepends=True)[-1][:40])  # half a record
    with caplog.at_level(logging.WARNING):
        s = read_session(copy)
    assert s.truncated and len(s.records) == n
    assert not s.complete
    assert "truncated" in caplog.text
    replay_session(s, Mode.S)  # replays up to the last complete tick


def test_bad_sessions_give_one_line_errors(ds_session: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad"
    shutil.copytree(ds_session, bad)
    (bad / "meta.json").write_text("{ not json")
    missing = tmp_path / "nope"
    mid = tmp_path / "mid"
    shutil.copytree(ds_session, mid)
    lines = (mid / "ticks.jsonl").read_text().splitlines()
    lines[3] = lines[3][:20]
    (mid / "ticks.jsonl").write_text("\n".join(lines) + "\n")
    for target, needle in (
        (bad, "meta.json: not a JSON file"),
        (missing, "not found"),
        (mid, "corrupt record"),
    ):
        r = subprocess.run(
            [*CLI, "replay", str(target), "--out", str(tmp_path / "o")],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 2, r.stderr
        assert needle in r.stderr and "Traceback" not in r.stderr
        assert r.stderr.strip().count("\n") == 0
    r = subprocess.run(
        [*CLI, "replay", str(ds_session), "--modes", "X", "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "unknown mode" in r.stderr


def test_a_killed_recording_replays_up_to_its_last_complete_tick(tmp_path: Path) -> None:
    folder = tmp_path / "killed"
    proc = subprocess.Popen(
        [
            *CLI,
            "run",
            "--source",
            "demo",
            "--realtime",
            "--record",
            str(folder),
            "--max-seconds",
            "60",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        ticks = folder / "ticks.jsonl"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if ticks.exists() and ticks.read_bytes().count(b"\n") >= 45:
                break
            time.sleep(0.1)
        else:
            pytest.fail("the recording did not start")
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    s = read_session(folder)
    assert not s.complete
    assert len(s.records) >= 45
    trace = replay_session(s, Mode.DS)
    assert len(trace.t_s) == len(s.records)
    r = subprocess.run(
        [*CLI, "replay", str(folder), "--modes", "DS", "--out", str(tmp_path / "o"), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr


@pytest.mark.slow
def test_the_real_videos_replay_through_the_whole_system(shared_data: Path, tmp_path: Path) -> None:
    videos = sorted((shared_data / "videos").glob("*.mp4"))
    assert len(videos) == 4
    out = tmp_path / "videos"
    r = subprocess.run(
        [*CLI, "replay", *map(str, videos), "--modes", "S,DS", "--out", str(out), "--workers", "2"],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert [s["name"] for s in m["episodes"]] == [v.name for v in videos]
    for s in m["episodes"]:
        assert s["duration_s"] > 3
        for mode in ("S", "DS"):
            row = s["modes"][mode]
            assert row["arbitrated_ticks"] > 10, (s["name"], mode)
            # The paper's cosine distance is a sum over actions, each in [0, 2]; the mean
            # per action beside it.
            assert row["actions"] > 0
            assert row["cosine_distance"] is not None
            assert 0 <= row["cosine_distance"] <= 2 * row["actions"]
            mean = row["cosine_distance_per_action_mean"]
            assert mean is not None and 0 <= mean <= 2
            assert mean == pytest.approx(row["cosine_distance"] / row["actions"])
            assert row["agreement"] is not None and 0 <= row["agreement"] <= 1
    # A clip that ends before the task's outcome is listed, never counted as a failed trial
    # (only episodes with an outcome count); these short clips end before it.
    counted = [s for s in m["episodes"] if s["counted"]]
    for s in m["episodes"]:
        ended = all(s["modes"][mode]["outcome"] != "none" for mode in ("S", "DS"))
        assert s["counted"] == ended
        assert s["end"] == ("video" if ended else "video ended before the outcome")
    for mode in ("S", "DS"):
        assert m["modes"][mode]["n"] == len(counted)
        assert m["modes"][mode]["excluded"] == 4 - len(counted)
    assert m["loop"] == "open"  # recorded hands replayed against a robot they never saw


@pytest.mark.slow
def test_a_video_session_records_its_frames_and_replays_retracked(
    shared_data: Path, tmp_path: Path
) -> None:
    video = shared_data / "videos" / "open_hand_wave_landscape.mp4"
    folder = tmp_path / "cam"
    r = subprocess.run(
        [*CLI, "run", "--source", f"video:{video}", "--record", str(folder), "--record-video"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    s = read_session(folder)
    assert s.video is not None and s.frames == folder / "frames.jsonl"
    out = tmp_path / "retracked"
    r = subprocess.run(
        [
            *CLI,
            "replay",
            str(folder),
            "--retrack",
            "--modes",
            "DS",
            "--out",
            str(out),
            "--no-plots",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr
    from dsteleop.app.replay.video import replay_retracked

    ((episode, trace),) = replay_retracked(s, [Mode.DS])
    assert episode.index == 0
    nan3 = np.full(3, np.nan)
    recorded = np.array(
        [
            r.hand.X_human.position if r.hand is not None and r.hand.X_human is not None else nan3
            for r in s.records
        ]
    )
    both = ~np.isnan(recorded[:, 0]) & ~np.isnan(trace.p_human[:, 0])
    assert both.sum() > 100
    # Re-tracking the re-encoded frames gives the same hand path to a few millimetres.
    err = np.linalg.norm(trace.p_human[both] - recorded[both], axis=1)
    assert np.median(err) < 0.005, np.median(err)


GOLDEN_V1 = Path(__file__).resolve().parent / "golden" / "schema1-demo-DS-spoon"
SAMPLES = sorted(p.name for p in RECORDINGS.iterdir() if (p / "meta.json").is_file())


def test_a_session_recorded_before_the_format_change_opens_and_replays() -> None:
    """The golden schema-1 session (tests/golden/README.md) opens, and replays against its
    recorded robot: the same ticks, the same goals and actions, the same outcome.

    What the arbitration derives from them changed where its reading changed since
    (docs/METHOD.md): eq (4)'s denominator floor is now a task-scale length instead of 1 mm,
    so P differs in the dimensions whose goal equals their start within a segment (y, whose
    pick goal is the start's y, and the fingers); P of x, z and the rotations is unchanged.
    eq (6)'s thresholds changed too (psi, B and alpha follow). The retired `eps_*` fields of
    the recorded configuration are read and dropped."""
    s = read_session(GOLDEN_V1)
    assert s.meta["schema"] == "dsteleop.session/1" and s.complete
    assert "eps_trans_m" in s.meta["loop"]["arbitration"]  # a retired field, read and dropped
    trace = replay_session(s, s.mode, robot="recorded")
    assert len(trace) == len(s.records)
    m = trace.arbitrated
    assert m.sum() == sum(r.step is not None for r in s.records) > 400
    for name in ("U_human", "U_robot"):
        recorded = np.array([getattr(r.step, name) for r in s.records if r.step is not None])
        np.testing.assert_allclose(getattr(trace.step, name)[m], recorded, atol=1e-6, rtol=0)
    moved = [s.dims.index(d) for d in ("x", "z", "roll", "pitch", "yaw")]
    for name in ("P_human", "P_robot"):
        recorded = np.array([getattr(r.step, name) for r in s.records if r.step is not None])
        got = getattr(trace.step, name)[m]
        np.testing.assert_allclose(got[:, moved], recorded[:, moved], atol=1e-6, rtol=0)
    assert np.isfinite(trace.step.alpha[m]).all() and np.isfinite(trace.step.B[m]).all()
    assert trace.outcome_name == _outcome(s.meta) == "success"


@pytest.mark.parametrize("folder", [RECORDINGS / n for n in SAMPLES], ids=str)
def test_the_sample_sessions_are_current(folder: Path) -> None:
    """The shipped sessions, replayed in their own mode against their recorded robot, give
    the alphas they recorded: the loop and the arbitration still compute what they did.
    Open loop, so it holds on any CPU (a closed-loop replay through PyBullet would amplify
    last-bit differences between machines). When the code changes what a run does,
    regenerate them with scripts/make_sample_sessions.sh."""
    assert len(SAMPLES) >= 3
    s = read_session(folder)
    assert s.meta["schema"] in READABLE
    assert s.complete and _outcome(s.meta) in ("success", "failure")
    recorded = recorded_alphas(s)
    trace = replay_session(s, s.mode, robot="recorded")
    np.testing.assert_allclose(trace.step.alpha[trace.arbitrated], recorded, atol=1e-9, rtol=0)
    assert trace.outcome_name == _outcome(s.meta)
