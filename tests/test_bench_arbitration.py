"""`dsteleop bench --only arbitration`: the JSON it prints (the timings themselves are figures
for docs/benchmarks.md, never asserted: these machines are shared and noisy)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np

from dsteleop.app.bench.arbitration import _tick_like
from dsteleop.arbitration import make_arbiter

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]


def test_quick_bench_prints_every_arbitration_figure() -> None:
    r = subprocess.run(
        [*CLI, "bench", "--only", "arbitration", "--quick"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["ds_step_us"]["n"] == 2000
    assert 0 < out["ds_step_us"]["median"] <= out["ds_step_us"]["p99"]
    # the headline batched figure: 1000 trajectories of 6 + 5 dims per call
    assert out["ds_batched_call_ms"]["batch"] == 1000 and out["ds_batched_call_ms"]["dims"] == 11
    cases = out["ds_batched_by_case"]
    assert out["ds_batched_call_ms"]["median"] == cases["11_dims_random"]["call_ms_median"]
    assert set(cases) == {
        "11_dims_random",
        "11_dims_tick_like",
        "6_dims_random",
        "6_dims_tick_like",
    }
    assert out["ds_batched_steps_per_s"] == cases["11_dims_random"]["steps_per_s"]
    mixed = out["modes_batched"]  # every registered mode in one batch
    assert {"S", "DS", "manual", "autonomous", "scalar"} <= set(mixed["modes"])
    assert mixed["steps_per_s"] > 0 and mixed["call_ms_median"] > 0
    assert {"DSC", "conf_scalar"} <= set(mixed["modes"])
    belief = out["dsc_belief_step_us"]  # a tick with inference over 3 candidates
    assert belief["n"] == 2000 and 0 < belief["median"] <= belief["p99"]
    for case in cases.values():
        assert case["steps_per_s"] > 0 and math.isfinite(case["call_ms_median"])
        # steps/s and the median call time are the same figure
        assert abs(case["steps_per_s"] * case["call_ms_median"] / 1e3 - 1000) < 5


def test_tick_like_states_look_like_a_tick() -> None:
    rng = np.random.default_rng(0)
    inp = _tick_like(rng, (200,), 5)
    for X in (inp.X_human, inp.X_human_prev, inp.X_current, inp.X_prev, inp.X_goal):
        R = X.rotation
        np.testing.assert_allclose(
            R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9
        )
        assert np.all((X.openness >= 0.0) & (X.openness <= 1.0))
    # one tick of motion between the previous and the current states, a few cm to the hand
    assert np.median(np.linalg.norm(inp.X_current.position - inp.X_prev.position, axis=-1)) < 0.02
    assert np.median(np.linalg.norm(inp.X_human.position - inp.X_current.position, axis=-1)) < 0.06
    arb = make_arbiter("DS")
    _, r = arb.step(arb.initial_state(11, (200,)), inp)
    assert np.all(np.isfinite(r.alpha)) and np.all((r.alpha >= 0.0) & (r.alpha <= 1.0))
