"""Runs a newcomer can trust (issue 23, items 1-4): reproducible runs, a loop rate the world
keeps, replay numbers that say what they are, and options that do what they say."""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dsteleop.app.cli.main import main
from dsteleop.app.compose import LoopOptions
from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.loop.timing import ManualClock, RateClock
from dsteleop.app.session.writer import HISTORY_FILE, META, TICKS
from dsteleop.arbitration import Mode

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"


def _summary(text: str) -> dict[str, Any]:
    """The command's one JSON line (the last line of stdout)."""
    return dict(json.loads(text.strip().splitlines()[-1]))


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, *argv], cwd=cwd, capture_output=True, text=True, timeout=900, check=False
    )


# --- 1: a run is a function of its inputs and seed ------------------------------------------


def test_the_same_run_three_times_gives_the_same_ticks_and_outcome(tmp_path: Path) -> None:
    """Three recorded runs side by side: no history carried from one to the next."""
    results = []
    for name in ("a", "b", "c"):
        proc = _run(["run", "--source", "demo", "--record", f"h/{name}"], tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        s = _summary(proc.stdout)
        results.append((s["ticks"], s["outcome"], s["events"]))
    assert results[0][1] != "none"
    assert results[0] == results[1] == results[2]
    assert not (tmp_path / "h" / HISTORY_FILE).exists()  # nothing kept behind the user's back
    meta = json.loads((tmp_path / "h" / "c" / META).read_text())
    assert meta["operator_history_file"] is None
    assert meta["operator_history"]["attempts"] == []


def test_history_is_explicit_and_its_path_and_hash_are_recorded(tmp_path: Path) -> None:
    hist = tmp_path / "me.json"
    for name in ("a", "b"):
        before = hist.read_bytes() if hist.exists() else None
        proc = _run(["run", "--source", "demo", "--history", str(hist), "--record", name], tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        meta = json.loads((tmp_path / name / META).read_text())
        src = meta["operator_history_file"]
        assert src["path"] == str(hist.resolve())
        if before is None:  # a new file: nothing read, an empty history
            assert src["sha256"] is None and meta["operator_history"]["attempts"] == []
        else:  # the file as this run read it: its hash, and its attempts in the metadata
            assert src["sha256"] == hashlib.sha256(before).hexdigest()
            assert meta["operator_history"] == json.loads(before)
            assert meta["operator_history"]["attempts"]
    assert json.loads(hist.read_text())["attempts"]  # the run's segments were appended


def test_a_history_file_that_is_a_folder_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--source", "demo", "--history", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--history" in err[0]


# --- 2: the rate and the world's time step agree; overruns are reported --------------------


@pytest.mark.parametrize("rate", ["5", "121", "100000", "nan"])
def test_a_rate_outside_the_documented_range_is_refused_with_the_reason(
    rate: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--source", "demo", "--rate", rate]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rate must be in 10-120 Hz" in err[0] and "world" in err[0]


def test_the_world_advances_one_loop_period_per_tick() -> None:
    """At 10 Hz a tick is 0.1 s of the world's time, at 60 Hz 1/60 s: the robot, the task
    and its time limit keep the loop's time."""
    from dsteleop.app.compose import build

    for rate in (10.0, 60.0):
        built = build(LoopOptions.of("demo", LoopConfig(rate_hz=rate)), realtime=False)
        try:
            built.loop.run_headless(max_ticks=12)
            env = built.loop.task.env  # type: ignore[attr-defined]
            assert env.dt_s == pytest.approx(1.0 / rate)
            assert env.robot.state().t_s == pytest.approx(12 / rate)
            assert built.loop.task.describe()["control_dt_s"] == pytest.approx(1.0 / rate)
        finally:
            built.close()


def test_a_demo_run_takes_about_the_same_world_time_at_any_rate() -> None:
    """The demo operator moves in seconds: at 20 and 60 Hz it finishes in about the same
    loop time (before, the world ran at 2/3 and 2x speed, and the time differed ~2x)."""
    from dsteleop.app.compose import build

    times = {}
    for rate in (20.0, 60.0):
        built = build(LoopOptions.of("demo", LoopConfig(rate_hz=rate)), realtime=False)
        try:
            built.loop.run_headless(max_ticks=int(150 * rate))
            assert built.loop.outcome, f"no outcome at {rate} Hz"
            times[rate] = built.loop.tick_index / rate
        finally:
            built.close()
    assert times[20.0] == pytest.approx(times[60.0], rel=0.3)


def test_a_sustained_overrun_share_is_measured_and_reported() -> None:
    from dsteleop.app.loop.timing import OVERRUN_WINDOW_S

    clock = ManualClock(0.0)
    rate = RateClock(30.0, clock)
    period = 1.0 / 30.0
    for k in range(round(OVERRUN_WINDOW_S * 30)):
        rate.wait()
        clock.advance(3 * period if k % 2 else period / 2)  # every other tick takes 3 periods
        rate.done()
    s = rate.summary()
    assert 0.4 <= s["overrun_share"] <= 0.6
    assert s["sustained_overrun"] is True
    assert rate.sustained_overrun


def test_the_page_status_shows_the_overrun_share() -> None:
    from dsteleop.app.viewer.panel import status_html
    from tests.fakes import ScriptedHand, fake_world

    robot, task = fake_world()
    loop = TeleopLoop(
        LoopConfig(), ScriptedHand(lambda t: robot.start), robot, task, ManualClock(0.0)
    )
    record = loop.tick(0.0)
    assert "overrun_share" in record.timing
    timing = {**record.timing, "overrun_share": 0.35}
    import dataclasses

    page = status_html(dataclasses.replace(record, timing=timing))
    assert "late 10 s" in page and "35 %" in page


def test_a_headless_summary_counts_its_ticks(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--source", "demo", "--max-seconds", "1"]) == 0
    s = _summary(capsys.readouterr().out)
    assert s["ticks"] == 30
    assert s["timing"]["ticks"] == 30 and s["timing"]["headless"] is True
    assert s["timing"]["tick_ms_p50"] > 0


# --- 3: replay's numbers say what they are ----------------------------------------------------


def test_a_video_that_ends_before_the_task_is_not_a_failed_trial() -> None:
    from dsteleop.app.replay import core
    from dsteleop.app.session.reader import read_session

    s = read_session(RECORDINGS / "demo-DS-spoon")
    view = s.of_episode(s.episodes[0])
    whole = core.as_recorded(view)
    cut = core.as_recorded(type(view)(view.folder, view.meta, view.records[:40], False))
    assert whole.outcome is not None and cut.outcome is None
    runs = [
        core.Run("clip.mp4", "clip.mp4", None, 1.3, cut),
        core.Run("full.mp4", "full.mp4", None, 10.0, whole),
    ]
    entries = core.episode_summaries(runs)
    assert [e["counted"] for e in entries] == [False, True]
    assert entries[0]["end"] == "video ended before the outcome"
    agg, _ = core.aggregate(entries, [whole.mode.value])
    assert agg[whole.mode.value]["n"] == 1 and agg[whole.mode.value]["excluded"] == 1


def test_a_replay_is_labelled_open_loop(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "o"
    argv = ["replay", str(RECORDINGS / "demo-DS-spoon"), "--robot", "recorded", "--modes", "DS"]
    assert main([*argv, "--workers", "1", "--out", str(out)]) == 0
    line = _summary(capsys.readouterr().out)
    metrics = json.loads((out / "metrics.json").read_text())
    assert line["loop"] == metrics["loop"] == "open"
    assert "open loop" in metrics["loop_note"]
    asrec = tmp_path / "r"
    assert main(["replay", str(RECORDINGS / "demo-DS-spoon"), "--as-recorded", "--no-plots",
                 "--workers", "1", "--out", str(asrec)]) == 0  # fmt: skip
    assert json.loads((asrec / "metrics.json").read_text())["loop"] == "closed"


def test_the_plots_say_open_loop_and_draw_each_goal_where_the_task_had_it() -> None:
    import matplotlib

    matplotlib.use("Agg")
    from dsteleop.app.replay import core
    from dsteleop.app.replay.plots import trajectory_figure
    from dsteleop.app.session.reader import read_session

    s = read_session(RECORDINGS / "demo-DS-spoon")
    view = s.of_episode(s.episodes[0])
    trace = core.as_recorded(view)
    fig = trajectory_figure(view.name, [trace], open_loop=True)
    assert "open loop" in fig.texts[0].get_text()  # the suptitle
    above = fig.axes[0]
    goals = {line.get_label(): np.array(line.get_xydata())[0] for line in above.get_lines()}
    plant = view.meta["plant"]
    for name in ("pick", "place"):
        p = np.array(plant[f"{name}_known"]["p"])
        np.testing.assert_allclose(goals[f"{name} goal"], p[[1, 0]], atol=1e-9)  # (y, x)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_as_recorded_with_modes_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["replay", str(RECORDINGS / "demo-DS-spoon"), "--as-recorded", "--modes", "S"]
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--modes" in err[0] and "--as-recorded" in err[0]


# --- 4: options that do what they say ---------------------------------------------------------


def _one_error_line(capsys: pytest.CaptureFixture[str], *words: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]


def test_record_video_with_the_demo_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["run", "--source", "demo", "--record-video", "--record", str(tmp_path / "s")]
    assert main(argv) == 2
    _one_error_line(capsys, "--record-video", "demo")
    assert not (tmp_path / "s").exists()


def test_a_realtime_demo_stopped_by_max_seconds_says_so(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["run", "--source", "demo", "--realtime", "--max-seconds", "2"]) == 0
    s = _summary(capsys.readouterr().out)
    assert s["stopped_by"] == "max-seconds"
    assert s["timing"]["ticks"] == 60 and "overrun_share" in s["timing"]


def test_rerun_at_a_folder_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "x.rrd"
    folder.mkdir()
    assert main(["run", "--source", "demo", "--rerun", str(folder)]) == 2
    _one_error_line(capsys, "--rerun", "folder")
    assert main(["replay", str(RECORDINGS / "demo-DS-spoon"), "--rerun", str(folder),
                 "--out", str(tmp_path / "o")]) == 2  # fmt: skip
    _one_error_line(capsys, "--rerun", "folder")


def test_rerun_connect_without_a_viewer_warns_and_says_so(
    capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    import socket

    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    addr = f"rerun+http://127.0.0.1:{port}/proxy"
    with caplog.at_level(logging.WARNING):
        argv = ["run", "--source", "demo", "--max-seconds", "1", "--rerun-connect", addr]
        assert main(argv) == 0
    s = _summary(capsys.readouterr().out)
    assert s["rerun"]["viewer_reachable"] is False
    assert any("no Rerun viewer listens" in r.getMessage() for r in caplog.records)


def test_a_fractional_window_says_it_must_be_whole(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--source", "demo", "--param", "window=2.5"]) == 2
    _one_error_line(capsys, "window", "whole number")
    assert main(["run", "--source", "demo", "--param", "window=x"]) == 2
    _one_error_line(capsys, "window", "not a number")


@pytest.mark.parametrize(
    ("flag", "value", "words"),
    [("--goal-noise", "10", "0-0.1 m"), ("--input-delay", "1e6", "0-1 s")],
)
def test_goal_noise_and_input_delay_beyond_their_bounds_are_refused(
    flag: str, value: str, words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    t0 = time.perf_counter()
    assert main(["run", "--source", "demo", flag, value]) == 2
    assert time.perf_counter() - t0 < 30  # refused at once, not after a 120 s timeout
    _one_error_line(capsys, flag, words)


def test_a_cut_last_tick_line_warns_once(tmp_path: Path) -> None:
    import shutil

    session = tmp_path / "cut"
    shutil.copytree(RECORDINGS / "demo-DS-spoon", session)
    ticks = session / TICKS
    text = ticks.read_text()
    ticks.write_text(text[: len(text) - 40])  # the last line cut short
    proc = _run(
        ["replay", str(session), "--robot", "recorded", "--modes", "DS", "--no-plots",
         "--out", str(tmp_path / "o")],
        tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stderr.count("truncated last record") == 1, proc.stderr


def test_the_page_refuses_a_parameter_outside_its_slider_and_says_why() -> None:
    """A browser tab sends kappa 50 and -5 (typed into the slider's box): neither reaches
    the loop, the page says why; kappa 8 reaches it."""
    import msgspec
    import viser
    import websockets
    from viser._messages import GuiUpdateMessage, ViewerCameraMessage

    from dsteleop.app.loop.broadcast import Broadcaster
    from dsteleop.app.loop.controls import Controls
    from dsteleop.app.viewer.server import Viewer, ViewerConfig

    controls = Controls()
    viewer = Viewer(Broadcaster(), controls, config=ViewerConfig(port=0))
    try:
        gui = viewer.server.gui
        kappa = next(
            h for h in gui._gui_input_handle_from_uuid.values() if h.label.startswith("kappa")
        )

        async def send(values: list[float]) -> list[Any]:
            url = viewer.url.replace("http://", "ws://")
            protocol: Any = f"viser-v{viser.__version__}"
            taken = []
            async with websockets.connect(url, subprotocols=[protocol], max_size=None) as ws:
                # A browser's first message is its camera; then Viser counts it as a client.
                hello = ViewerCameraMessage(
                    (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 1.0, 0.01, 100.0, 480, 640,
                    (0.0, 0.0, 0.0), (0.0, 0.0, 1.0),
                )  # fmt: skip
                await ws.send(msgspec.msgpack.encode(hello.as_serializable_dict()))
                await asyncio.sleep(0.5)
                for v in values:
                    msg = GuiUpdateMessage(kappa._impl.uuid, {"value": v})
                    await ws.send(msgspec.msgpack.encode(msg.as_serializable_dict()))
                    await asyncio.sleep(0.5)
                    taken.append((controls.take().params, viewer._refused_note.content))
            return taken

        (p50, note50), (pm5, note_m5), (p8, _) = asyncio.run(send([50.0, -5.0, 8.0]))
        assert p50 == {} and 'data-refused="kappa"' in note50 and "[0.5, 20], got 50" in note50
        assert pm5 == {} and "[0.5, 20], got -5" in note_m5
        assert p8 == {"kappa": 8.0}
        assert kappa.value == 8.0
    finally:
        viewer.close()


def test_recording_start_without_record_writes_to_the_user_data_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from dsteleop.app.cli import serve

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert serve.default_record_root() == tmp_path / "data" / "dsteleop" / "sessions"
    monkeypatch.delenv("XDG_DATA_HOME")
    root = serve.default_record_root()
    assert root.is_absolute() and root == Path.home() / ".local/share/dsteleop/sessions"


def test_the_loop_lists_every_recording_it_made(tmp_path: Path) -> None:
    """serve's summary names the page's recordings, also once they were stopped."""
    from tests.fakes import ScriptedHand, fake_world

    robot, task = fake_world()
    loop = TeleopLoop(
        LoopConfig(mode=Mode.DS),
        ScriptedHand(lambda t: robot.start),
        robot,
        task,
        ManualClock(0.0),
        record_root=tmp_path,
    )
    loop.controls.set_recording(True)
    loop.tick(0.0)
    loop.controls.set_recording(False)
    loop.tick(1 / 30)
    assert loop.recording is None
    assert len(loop.recordings) == 1 and loop.recordings[0].parent == tmp_path
    loop.close()


def test_an_explicit_input_delay_of_zero_switches_off_the_demo_worlds_delay() -> None:
    """The demo takes its world's link delay unless the user chose one: `--input-delay 0` is
    a choice (before, 0 meant "the world's value", so the delay could not be switched off)."""
    import argparse

    from dsteleop.app.cli.options import add_loop_options, loop_options
    from dsteleop.app.compose import build
    from dsteleop.app.operator.world import Impairments

    parser = argparse.ArgumentParser()
    add_loop_options(parser, "demo", "the session folder")
    delays = {}
    for extra in ([], ["--input-delay", "0"], ["--input-delay", "0.05"]):
        options = loop_options(parser.parse_args(["--source", "demo", *extra]))
        built = build(options, realtime=False)
        try:
            delays[" ".join(extra)] = built.loop.config.input_delay_s
        finally:
            built.close()
    assert delays == {
        "": Impairments().delay_s,
        "--input-delay 0": 0.0,
        "--input-delay 0.05": 0.05,
    }
