"""The live loop's goal inference (`--goal infer`): the belief the loop keeps over the
kitchen's candidates (app/loop/inference.py), its wiring into the tick and the record, the
demo person who changes its mind, and the command line.

The rates are over seeds of the demo (real PyBullet, the demo person through the tracking
pipeline), never bit for bit; the figures they were stated from are in docs/operator.md.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.loop import LoopConfig
from dsteleop.app.loop.inference import GoalInference
from dsteleop.app.replay.belief import belief_metrics_of, grasped_utensil, pick_beliefs
from dsteleop.app.session.schema import TickRecord
from dsteleop.arbitration import ArbitrationConfig, HandState, Mode
from dsteleop.arbitration.belief import BeliefParams
from dsteleop.arbitration.se3 import stack
from dsteleop.robot.task import Candidates

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
UTENSILS = ("spoon", "spatula", "ladle")
R_DOWN = np.diag([-1.0, 1.0, -1.0])
F = 4


def _candidates(x: Sequence[float] = (0.5, 0.58, 0.66), g: float = 1.0) -> Candidates:
    goals = stack([HandState(np.array([xi, 0.3, 0.3]), R_DOWN, np.full(F, g)) for xi in x])
    sigma = np.tile(np.r_[0.01, 0.008, 0.015, 0.05, 0.05, 0.05, np.zeros(F)], (len(x), 1))
    names = UTENSILS if len(x) == 3 else ("bin",)
    return Candidates(names, goals, sigma)


def _hand(x: float) -> HandState:
    return HandState(np.array([x, 0.3, 0.45]), R_DOWN, np.ones(F))


def test_the_belief_follows_the_hand_and_keeps_what_it_earned() -> None:
    inf = GoalInference()
    params = BeliefParams()
    c = _candidates()
    R = _hand(0.58)  # the robot where the hand starts
    first = inf.step(c, params, R, _hand(0.58), None)  # no hand before: no evidence
    assert np.allclose(first.record.probability, 1 / 3) and inf.updates == 0
    assert first.record.map_name == "spoon"  # ties: the first candidate
    prev = _hand(0.58)
    for x in np.linspace(0.585, 0.66, 20):  # the hand goes to the ladle, the robot follows
        now = inf.step(c, params, prev, _hand(x), prev)
        prev = _hand(x)
    assert now.record.map_name == "ladle" and now.record.probability[2] > 0.8
    assert np.allclose(now.goal.position, c.goals.position[2])
    # The MAP's own confidence: x is where the candidates disagree, y where they agree.
    assert now.confidence[1] > 0.9 and now.confidence[0] < now.confidence[1]
    held = inf.step(c, params, R, None, None)  # a lost hand is no evidence
    assert np.array_equal(held.record.probability, now.record.probability)
    # A candidate's fingers closing is the same candidates: the belief is kept.
    closed = _candidates()
    closed.goals.openness[2] = 0.0
    kept = inf.step(closed, params, R, None, None)
    assert np.array_equal(kept.record.probability, now.record.probability)
    assert np.allclose(kept.goal.openness, 0.0)
    # Other parameters from the next tick on: the belief is kept, the model is new.
    steeper = inf.step(closed, BeliefParams(beta=5.0), _hand(0.66), _hand(0.662), _hand(0.66))
    assert steeper.record.probability[2] > kept.record.probability[2]
    # Other candidates (the place phase): a new belief; a reset: the prior again.
    place = inf.step(_candidates((0.58,)), params, R, None, None)
    assert place.record.names == ("bin",) and place.record.probability.tolist() == [1.0]
    inf.reset()
    again = inf.step(c, params, R, None, None)
    assert np.allclose(again.record.probability, 1 / 3)


def test_the_floor_holds_whatever_the_evidence() -> None:
    inf = GoalInference()
    params = BeliefParams(beta=100.0, epsilon=0.01)
    c = _candidates()
    prev = _hand(0.4)
    lowest = 1.0
    for x in np.r_[np.linspace(0.4, 0.7, 200), np.linspace(0.7, 0.4, 200)]:
        out = inf.step(c, params, prev, _hand(x), prev)
        prev = _hand(x)
        lowest = min(lowest, float(out.record.probability.min()))
        assert out.record.probability.sum() == pytest.approx(1.0)
    assert lowest >= 0.01 - 1e-12 and lowest == pytest.approx(0.01)


def _demo(**options: Any) -> list[TickRecord]:
    """One headless demo run (`dsteleop run --source demo ...`); its records."""
    records: list[TickRecord] = []

    class Keep:
        def observe(self, record: TickRecord) -> None:
            records.append(record)

    built = build(LoopOptions.of("demo", **options), realtime=False, observers=(Keep(),))
    try:
        built.loop.run_headless(60 * 30)
    finally:
        built.close()
    return records


def test_a_robot_not_told_its_utensil_keeps_a_belief_in_the_loop() -> None:
    """The wiring: each tick's record holds the belief over the utensils, then the bin; the
    goal the robot sought is the MAP candidate's; no probability below the floor; the
    utensil grasped is the task's, and the robot was never told it."""
    records = _demo(goal="infer", utensil="spatula", seed=1)
    beliefs = [r.belief for r in records if r.belief is not None]
    assert len(beliefs) >= len(records) - 1
    eps = ArbitrationConfig().belief.epsilon
    assert min(float(b.probability.min()) for b in beliefs) >= eps - 1e-12
    assert {b.names for b in beliefs} == {UTENSILS, ("bin",)}
    picks = pick_beliefs([r.t_s for r in records], [r.belief for r in records])
    assert picks and all(b.names == UTENSILS for _, b in picks)
    meta_goal = {r.belief.map_name for r in records if r.belief and r.belief.names == ("bin",)}
    assert meta_goal == {"bin"}
    m = belief_metrics_of(records, 1 / 30)
    assert m is not None and m["candidates"] == list(UTENSILS)
    assert grasped_utensil(records) == "spatula" and m["map_right"]


def _rate(runs: Sequence[tuple[list[TickRecord], str]]) -> int:
    """How many runs grasped the utensil the person wanted (at the end) with the MAP on it."""
    n = 0
    for records, wanted in runs:
        m = belief_metrics_of(records, 1 / 30)
        n += bool(m is not None and m["grasped"] == wanted and m["map_final"] == wanted)
    return n


@pytest.mark.slow
def test_the_belief_finds_the_persons_utensil_in_the_demo_at_a_stated_rate() -> None:
    """Seeds 0-8 of the demo in DS, the person's utensil cycling with the seed (chance: 3 of
    9): the MAP at the end of the pick phase is the person's utensil in >= 7 of 9, whether or
    not the task then succeeded (a run that times out, as told runs do too, still says what
    the belief found; the demo's table in docs/operator.md counts the task's successes and
    this rate over seeds 0-19)."""
    found = []
    for seed in range(9):
        utensil = UTENSILS[seed % 3]
        m = belief_metrics_of(_demo(goal="infer", utensil=utensil, seed=seed), 1 / 30)
        found.append((seed, utensil, None if m is None else m["map_final"]))
    assert sum(want == got for _, want, got in found) >= 7, found


@pytest.mark.slow
def test_a_demo_person_who_changes_its_mind_mid_reach_is_followed() -> None:
    """Seeds 0-5: the person turns to the next utensil along the holder 1.5 s into the trial
    (mid-reach: its hand has moved), and the robot ends on that one: the MAP at the grasp and
    the utensil grasped, in >= 4 of 6 (measured over seeds 0-19 in docs/operator.md)."""
    runs = []
    for seed in range(6):
        first = UTENSILS[seed % 3]
        then = UTENSILS[(seed + 1) % 3]
        records = _demo(goal="infer", utensil=first, seed=seed, change_mind=(then, 1.5))
        beliefs = pick_beliefs([r.t_s for r in records], [r.belief for r in records])
        early = [b for t, b in beliefs if t < 1.5]
        assert early  # it did reach before it changed its mind
        runs.append((records, then))
    assert _rate(runs) >= 4


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--goal", "fork"], "--goal: unknown candidate 'fork'"),
        (["--goal", "spoon", "--utensil", "ladle"], "--utensil ladle with --goal spoon"),
        (["--utensil", "fork"], "--utensil: unknown utensil 'fork'"),
        (["--goal", "infer", "--change-mind", "ladel:1"], "unknown utensil 'ladel'"),
        (["--change-mind", "ladle:1"], "--change-mind with a robot told the spoon"),
        (["--goal", "infer", "--change-mind", "ladle"], "--change-mind needs UTENSIL:S"),
        (["--goal", "infer", "--param", "belief.beta=0"], "belief.beta must be in (0, 100]"),
    ],
)
def test_bad_goal_options_are_one_line_and_exit_2(
    argv: list[str], says: str, tmp_path: Path
) -> None:
    r = subprocess.run(
        [*CLI, "run", "--source", "demo", "--max-seconds", "1", *argv],
        capture_output=True, text=True, timeout=120, cwd=tmp_path, check=False,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and says in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_a_told_goal_keeps_its_old_meaning() -> None:
    """Without --goal the robot is told the person's utensil, as before the belief."""
    told = LoopOptions.of("demo", utensil="ladle")
    assert (told.goal, told.utensil, told.infer) == ("ladle", "ladle", False)
    default = LoopOptions.of("demo", loop=LoopConfig(mode=Mode.DS))
    assert (default.goal, default.utensil) == ("spoon", "spoon")
    infer = LoopOptions.of("demo", goal="infer")
    assert (infer.goal, infer.utensil, infer.infer) == ("infer", "spoon", True)


def test_replay_counts_and_plots_the_belief(tmp_path: Path) -> None:
    """A session of a robot inferring its goal, as recorded and replayed (the replay rebuilds
    the same candidates and keeps its own belief): metrics.json says per run and per mode
    what the belief did, and a plot shows it."""
    session = tmp_path / "s"
    r = subprocess.run(
        [*CLI, "run", "--source", "demo", "--goal", "infer", "--utensil", "ladle", "--seed",
         "4", "--record", str(session)],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    for extra in (["--as-recorded"], ["--modes", "DSC"]):
        out = tmp_path / f"out{len(extra)}"
        r = subprocess.run(
            [*CLI, "replay", str(session), "--out", str(out), *extra],
            capture_output=True, text=True, timeout=900, check=False,
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        import json

        metrics = json.loads((out / "metrics.json").read_text())
        (entry,) = metrics["episodes"]
        (mode,) = entry["modes"]
        b = entry["modes"][mode]["belief"]
        assert b["candidates"] == list(UTENSILS) and b["grasped"] in (*UTENSILS, None)
        assert 0 <= b["map_switches"] and set(b["confidence_mean"]) >= {"x", "y", "ring"}
        agg = metrics["modes"][mode]["belief"]
        assert agg["runs"] == 1 and agg["grasped"] in (0, 1)
        assert list(out.glob("*_belief.png")), sorted(p.name for p in out.iterdir())
