"""Running the study over processes: chunks of trajectories, one per worker.

Each trajectory is seeded by (seed, index) and the arbitration works row by row, so the
numbers do not depend on the number of workers (beyond the last bits).
"""

from __future__ import annotations

import itertools
import math
import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from dsteleop.app.cli.progress import Progress
from dsteleop.app.study.core import ChunkResult, SimConfig, StudyResult, merge, run_chunk
from dsteleop.arbitration.arbiters import compile_kernels
from dsteleop.errors import ConfigError


def workers_for(requested: int, trajectories: int) -> int:
    """Processes to use: `requested` (0: one per core, at most 4), never fewer than ~100
    trajectories each."""
    if requested < 0:
        raise ConfigError(f"--workers must be >= 0 (0: automatic), got {requested}")
    if requested == 0:
        requested = min(os.cpu_count() or 1, 4)
    return max(1, min(requested, math.ceil(trajectories / 100)))


_QUEUE: Any = None


def _init_worker(queue: Any) -> None:
    global _QUEUE  # noqa: PLW0603 - one queue per worker process, set once by the pool
    _QUEUE = queue
    # A worker ends by SIGTERM when the pool closes, whatever its parent was handling.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle


def _work(job: tuple[SimConfig, list[int]]) -> ChunkResult:
    cfg, indices = job
    return run_chunk(cfg, indices, on_progress=_QUEUE.put if _QUEUE is not None else None)


def simulate(
    cfg: SimConfig,
    workers: int,
    bar: Progress | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> StudyResult:
    """Run every trajectory under every mode; chunks over `workers` processes.

    Each trajectory is seeded by (seed, index) and the arbitration works row by row, so the
    numbers do not depend on `workers` (beyond the last bits). `meanwhile` runs in this
    process while the workers compute (after the run with one worker).
    """
    return simulate_all([cfg], workers, bar, meanwhile)[0]


def simulate_all(
    cfgs: Sequence[SimConfig],
    workers: int,
    bar: Progress | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> list[StudyResult]:
    """`simulate` for several studies at once, over one pool of workers."""
    if workers <= 1:
        out = []
        for cfg in cfgs:
            chunk = run_chunk(cfg, list(range(cfg.trajectories)), bar.advance if bar else None)
            out.append(merge(cfg, [chunk]))
        if meanwhile is not None:
            meanwhile()
        return out
    jobs = []
    for i, cfg in enumerate(cfgs):
        # One chunk per worker and study: bigger batches step more efficiently.
        bounds = np.linspace(0, cfg.trajectories, workers + 1).astype(int)
        jobs += [(i, cfg, list(range(a, b))) for a, b in itertools.pairwise(bounds) if b > a]
    fork = "fork" in mp.get_all_start_methods()
    if fork:
        # Forked workers inherit the compiled kernels loaded here, instead of each loading them
        # again (~0.5 s of numba's start-up per process) while this process does the same.
        compile_kernels()
    ctx = mp.get_context("fork" if fork else "spawn")
    queue = ctx.SimpleQueue()
    with ctx.Pool(workers, initializer=_init_worker, initargs=(queue,)) as pool:
        pending = pool.map_async(_work, [(cfg, idx) for _, cfg, idx in jobs], chunksize=1)
        if meanwhile is not None:
            meanwhile()
        while not pending.ready():
            pending.wait(0.1)
            while not queue.empty():
                done = queue.get()
                if bar:
                    bar.advance(done)
        chunks = pending.get()
        while not queue.empty():
            done = queue.get()
            if bar:
                bar.advance(done)
    return [
        merge(cfg, [c for (j, _, _), c in zip(jobs, chunks, strict=True) if j == i])
        for i, cfg in enumerate(cfgs)
    ]
