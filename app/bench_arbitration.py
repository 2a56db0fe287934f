"""Bench group `arbitration`: one DS step (6 + 5 dims) and the batched DS step."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from dsteleop.app.bench import percentiles_us
from dsteleop.arbitration import ArbitrationInput, HandState, make_arbiter, so3_exp


def _states(rng: np.random.Generator, batch: tuple[int, ...], n_fingers: int) -> HandState:
    return HandState(
        rng.uniform(-0.5, 0.5, (*batch, 3)),
        so3_exp(rng.normal(0.0, 1.0, (*batch, 3))),
        rng.uniform(0.0, 1.0, (*batch, n_fingers)),
    )


def _inputs(rng: np.random.Generator, batch: tuple[int, ...], n_fingers: int) -> ArbitrationInput:
    H, Hp, Hs, C, Cp, Cs, G = (_states(rng, batch, n_fingers) for _ in range(7))
    return ArbitrationInput(H, Hp, Hs, C, Cp, Cs, G, dt=1.0 / 30.0)


def run(quick: bool = False) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    n_fingers = 5
    arbiter = make_arbiter("DS")

    # Single step: many distinct random inputs, each timed alone.
    reps = 2000 if quick else 20000
    inputs = [_inputs(rng, (), n_fingers) for _ in range(min(reps, 500))]
    state = arbiter.initial_state(6 + n_fingers)
    samples = []
    for i in range(reps):
        inp = inputs[i % len(inputs)]
        t0 = time.perf_counter()
        state, _ = arbiter.step(state, inp)
        samples.append(time.perf_counter() - t0)

    # Batched: 1000 trajectories per call.
    batch = 1000
    binp = _inputs(rng, (batch,), n_fingers)
    bstate = arbiter.initial_state(6 + n_fingers, (batch,))
    calls = 20 if quick else 200
    bsamples = []
    for _ in range(calls):
        t0 = time.perf_counter()
        bstate, _ = arbiter.step(bstate, binp)
        bsamples.append(time.perf_counter() - t0)
    median_call_s = float(np.median(bsamples))
    return {
        "ds_step_us": percentiles_us(samples),
        "ds_batched_steps_per_s": round(batch / median_call_s),
        "ds_batched_call_ms": {
            "batch": batch,
            "median": round(median_call_s * 1e3, 3),
            "p95": round(float(np.percentile(bsamples, 95)) * 1e3, 3),
        },
    }
