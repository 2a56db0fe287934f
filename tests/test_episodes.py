"""Sessions hold episodes: one attempt at the task each, from a reset to its outcome.

The real loop with the demo operator and the PyBullet kitchen records a session over several
attempts: a time limit turns a stuck trial into a failure (`timeout`) and the task resets
for the next one; an attempt reset before its outcome is kept but not counted. The metadata
lists each episode as it ends; replay and metrics work per episode; statistics say their n
and when they mean nothing; sessions of older versions still read; an empty or
metadata-less session is refused with one line.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from dsteleop.app.cli.main import main
from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.loop import LoopConfig
from dsteleop.app.replay.core import MIN_EPISODES, aggregate
from dsteleop.app.session.reader import read_session
from dsteleop.app.session.schema import Status
from dsteleop.app.session.writer import META, TICKS
from dsteleop.arbitration import Mode
from tests.deadlines import wait_for

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "recordings" / "demo-DS-spoon"
GOLDEN_V1 = REPO / "tests" / "golden" / "schema1-demo-DS-spoon"
RATE_HZ = 30.0


def _meta(folder: Path) -> dict[str, Any]:
    return dict(json.loads((folder / META).read_text()))


@pytest.fixture(scope="module")
def attempts(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """A recording over 12 s of loop time: trials limited to 3 s, the task reset 1 s after
    each outcome, and one reset by the operator mid-trial (at 9 s). Returns the session
    folder and the metadata's episodes as they were while the loop still ran (after 5 s)."""
    folder = tmp_path_factory.mktemp("episodes") / "session"
    options = LoopOptions.of("demo", LoopConfig(mode=Mode.DS, reset_after_s=1.0), time_limit_s=3.0)
    built = build(options, realtime=False)
    loop = built.loop
    seen_live: list[dict[str, Any]] = []
    try:
        loop.start_recording(folder)
        for k in range(round(12.0 * RATE_HZ)):
            t = k / RATE_HZ
            loop.clock.sleep_until(t)
            if k == round(9.0 * RATE_HZ):
                loop.controls.reset()  # the operator gives up on this attempt
            loop.tick(t)
            if k == round(5.0 * RATE_HZ):
                # The recorder thread writes meta.json.
                wait_for(lambda: bool(_meta(folder).get("episodes")))
                seen_live = list(_meta(folder).get("episodes", []))
    finally:
        loop.close()
    return folder, seen_live


def test_each_attempt_is_an_episode_written_as_it_ends(
    attempts: tuple[Path, list[dict[str, Any]]],
) -> None:
    folder, seen_live = attempts
    # While the loop still ran, the first episode (a timeout at 3 s) was already written.
    assert len(seen_live) == 1 and seen_live[0]["outcome"]["reason"] == "timeout"
    meta = _meta(folder)
    episodes = meta["episodes"]
    assert meta["complete"] and meta["n_episodes"] == len(episodes)
    ends = [e["end"] for e in episodes]
    # 0-3 s timeout, reset at 4 s; 4-7 s timeout, reset at 8 s; 8-9 s abandoned (reset);
    # 9-12 s: a third trial that times out at 12 s, or is still open when recording stops.
    assert ends[:3] == ["outcome", "outcome", "reset"], ends
    assert ends[3:] in (["outcome"], ["stopped"]), ends
    for e in episodes[:2]:
        assert e["outcome"] == {
            "success": False,
            "reason": "timeout",
            "time_s": pytest.approx(3.0, abs=0.1),
            "utensil": "spoon",
        }
        assert e["duration_s"] == pytest.approx(3.0, abs=0.1)
        assert any(ev.startswith("failure:timeout") for _, ev in e["events"])
    assert episodes[2]["outcome"] is None and episodes[2]["duration_s"] == pytest.approx(1, abs=0.1)
    assert [e["index"] for e in episodes] == list(range(len(episodes)))
    # The ticks between an outcome and the next reset belong to no episode.
    assert episodes[1]["first_tick"] > episodes[0]["last_tick"] + 0.9 * RATE_HZ
    # A reader splits the ticks into the same episodes.
    session = read_session(folder)
    assert [e.to_dict() for e in session.episodes] == episodes
    # After an outcome the status says so: finished with the outcome, not lost.
    done = [r for r in session.records if r.outcome is not None]
    after = [r for r in done if r.status is Status.FINISHED]
    assert after and all(r.reason == "failure (timeout)" for r in after)
    assert not any(r.reason == "task finished" for r in session.records)


def test_replay_and_metrics_work_per_episode(
    attempts: tuple[Path, list[dict[str, Any]]], tmp_path: Path
) -> None:
    folder, _ = attempts
    out = tmp_path / "out"
    argv = ["replay", str(folder), "--robot", "recorded", "--modes", "DS,S", "--no-plots"]
    assert main([*argv, "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    entries = m["episodes"]
    n = len(_meta(folder)["episodes"])
    assert [e["name"] for e in entries] == [f"{folder.name}/ep{i}" for i in range(n)]
    # Against the recorded robot each episode replays to its own recorded outcome.
    for e, rec in zip(entries, _meta(folder)["episodes"]):
        assert e["end"] == rec["end"] and e["counted"] == (rec["end"] == "outcome")
        if rec["end"] == "outcome":
            assert e["modes"]["DS"]["outcome"] == "failure"
            assert e["modes"]["DS"]["time_s"] == pytest.approx(rec["duration_s"], abs=0.05)
    counted = sum(e["counted"] for e in entries)
    for mode in ("DS", "S"):
        assert m["modes"][mode]["n"] == counted and m["modes"][mode]["excluded"] == n - counted
    test = m["tests"]["DS_vs_S"]
    assert test["n"] == [counted, counted] and test["meaningful"] is False
    assert "not meaningful" in test["note"]


def test_statistics_say_their_n_and_when_they_mean_nothing() -> None:
    def entry(mode_rows: dict[str, tuple[bool, float]], counted: bool = True) -> dict[str, Any]:
        modes = {
            m: {"success": s, "time_s": t, "cosine_distance": 0.3 + t / 100, "agreement": 0.5}
            for m, (s, t) in mode_rows.items()
        }
        return {"modes": modes, "counted": counted}

    few = [entry({"S": (k % 2 == 0, 10.0 + k), "DS": (True, 8.0 + k)}) for k in range(2)]
    agg, tests = aggregate([*few, entry({"S": (False, 1), "DS": (False, 1)}, False)], ["S", "DS"])
    assert agg["S"]["n"] == 2 and agg["S"]["excluded"] == 1
    assert tests["S_vs_DS"]["n"] == [2, 2] and not tests["S_vs_DS"]["meaningful"]
    many = [
        entry({"S": (k % 3 == 0, 10.0 + k), "DS": (k % 4 != 0, 8.0 + k)})
        for k in range(MIN_EPISODES)
    ]
    agg, tests = aggregate(many, ["S", "DS"])
    assert tests["S_vs_DS"]["meaningful"] and "note" not in tests["S_vs_DS"]
    assert "success_n1_chi2" in tests["S_vs_DS"] and agg["DS"]["n"] == MIN_EPISODES


def test_sessions_of_older_versions_read_as_one_episode(tmp_path: Path) -> None:
    # Schema 2: the same files, the metadata without episodes.
    v2 = tmp_path / "v2"
    shutil.copytree(SAMPLE, v2)
    meta = _meta(v2)
    meta.pop("episodes")
    (v2 / META).write_text(json.dumps({**meta, "schema": "dsteleop.session/2"}))
    for folder in (v2, GOLDEN_V1):
        s = read_session(folder)
        (episode,) = s.episodes
        assert episode.end == "outcome" and episode.counted and episode.outcome is not None
        assert episode.first == 0 and episode.last == len(s.records) - 1
        assert episode.utensil == "spoon"


def test_an_empty_session_is_refused_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    empty = tmp_path / "empty"
    shutil.copytree(SAMPLE, empty)
    (empty / TICKS).write_text("")
    assert main(["replay", str(empty), "--modes", "DS", "--out", str(tmp_path / "o")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "empty session" in line and str(empty) in line


def test_a_session_without_metadata_is_refused_not_replayed_as_a_video(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import numpy as np

    from tests.videos import write_mp4

    lost = tmp_path / "sessions" / "lost-meta"
    lost.mkdir(parents=True)
    shutil.copy(SAMPLE / TICKS, lost / TICKS)
    write_mp4(lost / "video.mp4", [np.full((48, 64, 3), 90, np.uint8)] * 10)
    (lost / "frames.jsonl").write_text("")
    for target in (lost, lost.parent):  # the folder itself, or a folder of sessions
        out = tmp_path / f"o-{target.name}"
        assert main(["replay", str(target), "--modes", "DS", "--out", str(out)]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert "without its meta.json" in line and "lost-meta" in line
    # `tune --sessions` reads a folder of sessions the same way: refused, not skipped.
    good = tmp_path / "sessions" / "good"
    shutil.copytree(SAMPLE, good)
    for target in (lost, lost.parent):
        out = tmp_path / f"t-{target.name}"
        args = ["tune", "--no-progress", "--trials", "1", "--out", str(out)]
        assert main([*args, "--objective", "sessions", "--sessions", str(target)]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.startswith("dsteleop tune: error:")
        assert "without its meta.json" in line and "lost-meta" in line


def test_the_trajectory_plot_has_metres_goals_and_phases() -> None:
    from dsteleop.app.replay.core import as_recorded
    from dsteleop.app.replay.plots import trajectory_figure

    session = read_session(SAMPLE)
    trace = as_recorded(session.of_episode(session.episodes[0]))
    fig = trajectory_figure("demo", [trace])
    above, front, over_time = fig.axes[:3]
    for ax in (above, front):
        assert "[m]" in ax.get_xlabel() and "[m]" in ax.get_ylabel()
        labels = ax.get_legend_handles_labels()[1]
        assert "pick goal" in labels and "place goal" in labels
    assert over_time.get_xlabel() == "time [s]" and "[m]" in over_time.get_ylabel()
    box = over_time.get_legend()
    assert box is not None
    legend = [t.get_text() for t in box.get_texts()]
    assert {"phase pick", "phase place", "phase done"} <= set(legend)
    # The phases shaded: one span per stretch of a phase (pick, then place, then done).
    assert len(over_time.patches) >= 3
