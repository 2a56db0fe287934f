"""Every path a command writes is checked at start-up, and a failed command leaves no empty
output folder behind (issue 34, "Crashes and surprises"; `app/outpaths.py`).

Before: an unwritable `--history` ended the loop mid-trial with a traceback (the file is
first written at the first finished segment); an unwritable `--rerun` file or `track --out`
was a traceback and exit code 1; a `tune` or `replay` that failed left its new `--out`
folder behind, empty; a `--record-lerobot` run killed in its first episode left a folder
that looked empty (a hidden folder of sessions) and that the next run refused as "not empty".
"""

from __future__ import annotations

import argparse
import importlib
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from dsteleop.app.cli.main import COMMANDS, main
from dsteleop.app.lerobot import SESSIONS
from dsteleop.app.outpaths import (
    OutputPath,
    check_output_dir,
    check_output_file,
    created_dir,
    unwritable,
)
from dsteleop.errors import InputError

REPO = Path(__file__).resolve().parents[1]
SESSION = REPO / "recordings" / "demo-S-spoon"
CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]


@pytest.fixture
def locked(tmp_path: Path) -> Iterator[Path]:
    """A folder in which no file can be made, for whoever runs the tests: a read-only folder
    of ours (root writes there anyway), else /sys (read-only for root too)."""
    ro = tmp_path / "read-only"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        for folder in (ro, Path("/sys")):
            if folder.is_dir() and unwritable(folder) is not None:
                yield folder
                return
        pytest.skip("no folder here refuses a new file (root, and no read-only /sys)")
    finally:
        ro.chmod(0o700)


def _one_line(capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert captured.out == "", "the command ran: " + captured.out[:200]
    return lines[0]


def test_an_unwritable_history_is_refused_before_the_run_starts(
    locked: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["run", "--source", "demo", "--history", str(locked / "history.json")])
    assert code == 2
    _one_line(capsys, "dsteleop run: error: --history", "cannot write", str(locked))


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["run", "--source", "demo", "--rerun", "{locked}/run.rrd"], "--rerun"),
        (["run", "--source", "demo", "--record", "{locked}/session"], "--record"),
        (["run", "--source", "demo", "--record-lerobot", "{locked}/ds"], "--record-lerobot"),
        (["serve", "--source", "demo", "--port", "0", "--rerun", "{locked}/s.rrd"], "--rerun"),
        (["track", "synthetic", "--duration", "0.2", "--out", "{locked}/t.jsonl"], "--out"),
        (
            ["track", "synthetic", "--out", "{tmp}/t.jsonl", "--preview", "{locked}/p.mp4"],
            "--preview",
        ),
        (["replay", str(SESSION), "--out", "{locked}/r"], "--out"),
        (["replay", str(SESSION), "--out", "{tmp}/r", "--rerun", "{locked}/r.rrd"], "--rerun"),
        (["sim", "--trajectories", "5", "--out", "{locked}/sim"], "--out"),
        (["tune", "--objective", "study", "--trials", "1", "--out", "{locked}/tune"], "--out"),
        (["export", str(SESSION), "--to", "lerobot", "--out", "{locked}/ds"], "--out"),
    ],
)
def test_every_output_that_cannot_be_written_is_one_line_before_anything_runs(
    locked: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    option: str,
) -> None:
    args = [a.replace("{locked}", str(locked)).replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(args) == 2
    _one_line(capsys, f"dsteleop {argv[0]}: error: {option}", "cannot write")
    assert not (tmp_path / "t.jsonl").exists() and not (tmp_path / "r").exists()


def test_a_file_on_the_way_or_a_folder_for_a_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("mine")
    assert main(["track", "synthetic", "--out", str(tmp_path)]) == 2
    _one_line(capsys, "--out must name a file, got the folder")
    assert main(["replay", str(SESSION), "--out", str(blocker / "sub")]) == 2
    _one_line(capsys, "--out: cannot write to", "is not a folder")
    assert main(["run", "--source", "demo", "--history", str(blocker / "h.json")]) == 2
    _one_line(capsys, "--history: no such folder")
    assert blocker.read_text() == "mine"


def test_the_checks_create_nothing_and_pass_what_can_be_written(tmp_path: Path) -> None:
    existing = tmp_path / "history.json"
    existing.write_text("{}")
    assert check_output_file(existing, "--history") == existing
    assert existing.read_text() == "{}"  # opened for appending, nothing written
    assert check_output_file(tmp_path / "new.rrd", "--rerun") == tmp_path / "new.rrd"
    assert check_output_dir(tmp_path / "a" / "b", "--out") == tmp_path / "a" / "b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["history.json"]
    with pytest.raises(InputError, match="regular file"):
        check_output_file(Path("/dev/null"), "--history")  # a write would replace the device


def test_every_output_option_of_every_command_is_checked() -> None:
    """The options that name something a command writes are marked `output_file` or
    `output_dir`, so `main` checks them (a new one unmarked fails here)."""
    outputs = {"--out", "--record", "--record-lerobot", "--rerun", "--history", "--preview"}
    seen = set()
    for name, (module, _help) in COMMANDS.items():
        parser = argparse.ArgumentParser()
        importlib.import_module(module).add_arguments(parser)
        for action in parser._actions:
            for option in set(action.option_strings) & outputs:
                assert isinstance(action.type, OutputPath), f"{name} {option}"
                seen.add((name, option))
    for expected in [("run", "--history"), ("serve", "--record"), ("track", "--out")]:
        assert expected in seen


def test_a_failed_replay_or_tune_removes_the_out_folder_it_created(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "meta.json").write_text("{")  # a session whose metadata does not read
    (bad / "ticks.jsonl").write_text("")
    assert main(["replay", str(bad), "--out", str(tmp_path / "new" / "replay")]) == 2
    _one_line(capsys, "session metadata", "meta.json: not a JSON file")
    assert not (tmp_path / "new").exists()
    argv = ["tune", "--objective", "study", "--trials", "1", "--resume"]
    assert main([*argv, "--out", str(tmp_path / "tune")]) == 2
    _one_line(capsys, "--resume: no tuning study")
    assert not (tmp_path / "tune").exists()
    # A folder that was there before stays, empty or not.
    mine = tmp_path / "mine"
    mine.mkdir()
    assert main([*argv, "--out", str(mine)]) == 2
    _one_line(capsys, "--resume: no tuning study")
    assert mine.is_dir()


def test_created_dir_removes_only_the_empty_folders_it_made(tmp_path: Path) -> None:
    top = tmp_path / "top"
    with pytest.raises(RuntimeError), created_dir(top / "a" / "b") as out:
        raise RuntimeError("the command failed")
    assert not top.exists() and out == top / "a" / "b"
    # Something written: everything stays.
    with pytest.raises(KeyboardInterrupt), created_dir(top / "a" / "b") as out:
        (out / "trials.csv").write_text("1\n")
        raise KeyboardInterrupt
    assert (top / "a" / "b" / "trials.csv").read_text() == "1\n"
    # Something written beside it, in a parent it made: that parent stays (and so its own).
    other = tmp_path / "other"
    with pytest.raises(RuntimeError), created_dir(other / "a" / "b") as out:
        (other / "a" / "note").write_text("x")
        raise RuntimeError
    assert not out.exists() and (other / "a" / "note").is_file()
    # Success keeps the folder, empty or not.
    with created_dir(tmp_path / "kept") as out:
        pass
    assert out.is_dir()


def _lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines() if path.is_file() else []


def test_a_live_dataset_killed_in_its_first_episode_says_what_is_left_and_what_to_do(
    tmp_path: Path,
) -> None:
    ds = tmp_path / "ds"
    run = [*CLI, "run", "--source", "demo", "--record-lerobot", str(ds)]
    proc = subprocess.Popen([*run, "--realtime"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    ticks: list[Path] = []
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and proc.poll() is None:
            ticks = list((ds / SESSIONS).glob("*/ticks.jsonl"))
            if ticks and len(_lines(ticks[0])) >= 15:  # half a second into its first trial
                break
            time.sleep(0.05)
    finally:
        proc.kill()  # SIGKILL: no cleanup at all, as a crash or a power cut
        proc.communicate(timeout=30)
    assert ticks and not (ds / "meta").exists(), "the run ended before it was killed"
    recorded = _lines(ticks[0])
    # The next run into the same folder: one line saying what is there and what to do.
    r = subprocess.run(run, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and f"only {SESSIONS}/" in line and "1 session(s)" in line, line
    assert "ended before its first episode was written" in line and "move" in line, line
    assert _lines(ticks[0]) == recorded  # the killed run's ticks are untouched
    # Doing what it says (its session moved elsewhere) makes the folder reusable.
    kept = tmp_path / "kept"
    shutil.move(ds / SESSIONS, kept)
    r = subprocess.run(run, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr
    assert (ds / "meta" / "info.json").is_file()
    assert _lines(kept / ticks[0].parent.name / "ticks.jsonl") == recorded
    # A folder that holds a dataset is named as one.
    r = subprocess.run(run, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 2 and "holds a dataset already" in r.stderr, r.stderr


def test_a_history_that_stops_being_writable_mid_run_is_one_error_not_a_traceback(
    locked: Path,
) -> None:
    """Checked at start-up, the file can still become unwritable later (a full disk): the
    save at a finished segment is then one `InputError` naming `--history`."""
    from dsteleop.app.session.writer import HistoryFile
    from dsteleop.arbitration.history import OperatorHistory

    with pytest.raises(InputError, match=r"--history .*: cannot write the operator history"):
        HistoryFile(locked / "history.json").save(OperatorHistory())
