"""Bench group `arbitration`: the one arbitration kernel (`arbitration/arbiters.py`) in DS mode.

    ds_step_us              one unbatched step (a batch of one, as the 30 Hz loop runs it),
                            6 + 5 dims: median, p95, p99 [us] over many distinct inputs
    ds_batched_steps_per_s  1000 trajectories per call, 6 + 5 dims, random states
    ds_batched_call_ms      the same calls: median and p95 [ms]
    ds_batched_by_case      the batched step per dims (11, 6) and states (random, tick_like)
    modes_batched           1000 rows of 6 + 5 dims, random states, mixing every registered
                            mode row by row (as the simulation study steps its modes):
                            steps_per_s and call_ms_median
    dsc_belief_step_us      one unbatched tick with goal inference, as the loop runs it
                            (`app.loop.inference.GoalInference.step`): the belief over 3
                            candidates updated from the hand's motion, its confidence and MAP
                            goal, then one DSC step (a batch of one, 6 + 5 dims): median, p95,
                            p99 [us]; target < 1000 us
    ds_belief_step_us       the same with a DS step (DS reads no confidence: the inference's
                            cost on top of DS's)

The headline figures use independent random states (the worst case: random rotations put some
pairs near pi, and erfc is slowest for the large arguments unrelated states give). The batched
step is also timed on tick-like states (the current pose between start and goal, the previous
ones a tick away, the hand near the robot: what a session or the simulation study feeds it)
and with 6 dims, the simulation study's planar workload, under `ds_batched_by_case`.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from dsteleop.app.bench import percentiles_us
from dsteleop.app.loop.inference import GoalInference
from dsteleop.arbitration import (
    ArbitrationInput,
    HandState,
    RowModes,
    make_arbiter,
    registered,
    so3_exp,
)
from dsteleop.arbitration.arbiters import Arbiter
from dsteleop.arbitration.belief import BeliefParams
from dsteleop.robot.task import Candidates


def _states(rng: np.random.Generator, batch: tuple[int, ...], n_fingers: int) -> HandState:
    return HandState(
        rng.uniform(-0.5, 0.5, (*batch, 3)),
        so3_exp(rng.normal(0.0, 1.0, (*batch, 3))),
        rng.uniform(0.0, 1.0, (*batch, n_fingers)),
    )


def _inputs(rng: np.random.Generator, batch: tuple[int, ...], n_fingers: int) -> ArbitrationInput:
    H, Hp, Hs, C, Cp, Cs, G = (_states(rng, batch, n_fingers) for _ in range(7))
    return ArbitrationInput(
        X_human=H,
        X_human_prev=Hp,
        X_human_start=Hs,
        X_current=C,
        X_prev=Cp,
        X_start=Cs,
        X_goal=G,
        dt=1.0 / 30.0,
    )


def run(quick: bool = False) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    n_fingers = 5
    arbiter = make_arbiter("DS")

    # Single step (batch shape (), the loop's): many distinct random inputs, each timed alone.
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
    calls = 20 if quick else 200
    cases = {}
    for dims in (11, 6):
        for kind, make in (("random", _inputs), ("tick_like", _tick_like)):
            bsamples = _batched_samples(arbiter, make(rng, (batch,), dims - 6), batch, calls)
            cases[f"{dims}_dims_{kind}"] = {
                "steps_per_s": round(batch / float(np.median(bsamples))),
                "call_ms_median": round(float(np.median(bsamples)) * 1e3, 3),
                "call_ms_p95": round(float(np.percentile(bsamples, 95)) * 1e3, 3),
            }
    head = cases["11_dims_random"]
    modes = registered()
    mixed = RowModes.of([modes[k % len(modes)] for k in range(batch)])
    msamples = _batched_samples(arbiter, _inputs(rng, (batch,), 5), batch, calls, mixed)
    return {
        "ds_step_us": percentiles_us(samples),
        "ds_batched_steps_per_s": head["steps_per_s"],
        "ds_batched_call_ms": {
            "batch": batch,
            "dims": 11,
            "median": head["call_ms_median"],
            "p95": head["call_ms_p95"],
        },
        "ds_batched_by_case": cases,
        "modes_batched": {
            "modes": [m.value for m in modes],
            "steps_per_s": round(batch / float(np.median(msamples))),
            "call_ms_median": round(float(np.median(msamples)) * 1e3, 3),
        },
        "dsc_belief_step_us": percentiles_us(_belief_samples(rng, n_fingers, reps, "DSC")),
        "ds_belief_step_us": percentiles_us(_belief_samples(rng, n_fingers, reps, "DS")),
    }


def _row(X: HandState) -> HandState:
    """The one row of a batch of one."""
    return HandState(X.position[0], X.rotation[0], X.openness[0])


def _belief_samples(rng: np.random.Generator, n_fingers: int, reps: int, mode: str) -> list[float]:
    """Seconds per tick of the loop's inference (update, confidence, MAP goal) + a `mode`
    step, 3 candidates (the same candidates every tick, as within a phase)."""
    goals = _states(rng, (3,), n_fingers)
    candidates = Candidates(("a", "b", "c"), goals, np.full((3, 6 + n_fingers), 0.01))
    inference = GoalInference()
    params = BeliefParams()
    arbiter = make_arbiter(mode)
    inputs = [_inputs(rng, (1,), n_fingers) for _ in range(min(reps, 500))]
    state = arbiter.initial_state(6 + n_fingers, (1,))
    samples = []
    for i in range(reps):
        inp = inputs[i % len(inputs)]
        t0 = time.perf_counter()
        got = inference.step(
            candidates, params, _row(inp.X_current), _row(inp.X_human), _row(inp.X_human_prev)
        )
        tick = ArbitrationInput(
            X_human=inp.X_human, X_human_prev=inp.X_human_prev, X_human_start=inp.X_human_start,
            X_current=inp.X_current, X_prev=inp.X_prev, X_start=inp.X_start,
            X_goal=HandState(got.goal.position[None], got.goal.rotation[None],
                             got.goal.openness[None]),
            dt=inp.dt, confidence=got.confidence[None], confidence_joint=got.confidence_joint,
        )  # fmt: skip
        state, _ = arbiter.step(state, tick)
        samples.append(time.perf_counter() - t0)
    return samples


def _batched_samples(
    arbiter: Arbiter,
    inp: ArbitrationInput,
    batch: int,
    calls: int,
    rows: RowModes | None = None,
) -> list[float]:
    """Seconds per call of the batched step (DS, or the modes `rows`), the filter state
    carried from call to call."""
    state = arbiter.initial_state(6 + inp.X_current.n_fingers, (batch,))
    samples = []
    for _ in range(calls):
        t0 = time.perf_counter()
        state, _ = arbiter.step(state, inp, rows)
        samples.append(time.perf_counter() - t0)
    return samples


def _tick_like(
    rng: np.random.Generator, batch: tuple[int, ...], n_fingers: int
) -> ArbitrationInput:
    """States shaped like a real tick: the robot part-way from its start to the goal, its
    previous state one tick of motion away, the hand a few cm and degrees off the robot and
    one tick from its own previous state, the hand's start near the robot's."""

    def near(X: HandState, dp: float, dr: float, dg: float) -> HandState:
        return HandState(
            X.position + rng.normal(0.0, dp, (*batch, 3)),
            so3_exp(rng.normal(0.0, dr, (*batch, 3))) @ X.rotation,
            np.clip(X.openness + rng.normal(0.0, dg, (*batch, n_fingers)), 0.0, 1.0),
        )

    start = _states(rng, batch, n_fingers)
    goal = near(start, 0.2, 0.5, 0.4)
    s = rng.uniform(0.0, 1.0, (*batch, 1))
    cur = near(
        HandState(
            start.position + s * (goal.position - start.position),
            start.rotation,
            start.openness + s * (goal.openness - start.openness),
        ),
        0.01,
        0.3,
        0.01,
    )
    prev = near(cur, 0.005, 0.01, 0.01)
    hum = near(cur, 0.02, 0.1, 0.05)
    hum_prev = near(hum, 0.005, 0.01, 0.01)
    hum_start = near(start, 0.02, 0.05, 0.02)
    return ArbitrationInput(
        X_human=hum,
        X_human_prev=hum_prev,
        X_human_start=hum_start,
        X_current=cur,
        X_prev=prev,
        X_start=start,
        X_goal=goal,
        dt=1.0 / 30.0,
    )
