"""`dsteleop bench --only study`: the study's time in both worlds, as the command a user
runs (the seconds are figures for docs/benchmarks.md and the README, never asserted: these
machines are shared and noisy)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dsteleop.app.bench import study

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]


@pytest.mark.slow
def test_quick_bench_times_both_worlds_with_the_load_beside_each_run() -> None:
    r = subprocess.run(
        [*CLI, "bench", "--only", "study", "--quick"], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["machine"]["cores"] and out["machine"]["cpu"]
    s = out["study"]
    assert s["trajectories"] == 100 and s["target_s"] == 15.0 and s["warmup_s"] > 0
    for world in ("default", "objects"):
        runs = s[world]["seconds"]
        assert len(runs) == 1 and runs[0] > 0 and s[world]["median_s"] == runs[0]
        assert len(s[world]["load_average_before"]) == 1
        assert s[world]["within_target"] is None  # judged only at 1000 people


def test_a_study_that_fails_stops_the_bench_with_its_last_line(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match=r"bench study: .*--world nosuch.*failed: .*nosuch"):
        study._sim(10, ("--world", "nosuch"), tmp_path / "out")
