"""The built-in demo end to end: the closed-loop demo person, the tracking pipeline, the loop
and the PyBullet robot, as rates over seeds (closed-loop physics amplifies last-bit
differences between CPUs, so no single run's outcome is tested)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.loop import LoopConfig
from dsteleop.arbitration import Mode

SEEDS = range(10)
MAX_TICKS = 3700  # the task's own timeout (120 s) decides a stuck run


def outcome(mode: Mode, seed: int) -> str:
    built = build(LoopOptions.of("demo", LoopConfig(mode=mode), seed=seed), realtime=False)
    try:
        built.loop.run_headless(MAX_TICKS)
        return built.loop.outcome or "none"
    finally:
        built.loop.close()


@pytest.mark.slow
@pytest.mark.parametrize("mode", [Mode.DS, Mode.S, Mode.MANUAL])
def test_the_demo_succeeds_on_most_seeds(mode: Mode) -> None:
    """Measured on this project's machines in the operator's world (docs/operator.md: goal
    noise 2 cm, a 0.2 s delay each way, depth misjudged through the one camera): 7 of seeds
    0-9 succeed in each of DS, S and manual (before the world, without delay or depth error
    and with 1 cm goal noise: at least 9). The test allows one more failure, for another
    CPU's physics."""
    outcomes = [outcome(mode, s) for s in SEEDS]
    assert "none" not in outcomes, outcomes  # every run ends, with an outcome
    assert outcomes.count("success") >= 6, outcomes


def test_run_prints_the_outcome_in_its_json_line() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "run", "--source", "demo", "--seed", "1"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    line = json.loads(proc.stdout.strip().splitlines()[-1])
    assert line["outcome"] in ("success", "failure") and line["seed"] == 1
    assert line["mode"] == "DS" and line["source"] == "demo"
    assert any(e.split(":")[1] in ("success", "failure") for e in line["events"])
