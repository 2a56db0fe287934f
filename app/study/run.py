"""Running the study over processes: chunks of trajectories, one per worker.

Each trajectory is seeded by (seed, index) and the arbitration works row by row, so the
numbers do not depend on the number of workers (beyond the last bits).
"""

from __future__ import annotations

import ctypes
import functools
import itertools
import math
import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Sequence
from multiprocessing.queues import SimpleQueue

import numpy as np

from dsteleop.app.study.batch import run_chunk
from dsteleop.app.study.planar import SimConfig
from dsteleop.app.study.results import ChunkResult, StudyResult, merge
from dsteleop.app.tasks.progress import Progress
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


#: glibc's mallopt parameters: the trim threshold and the mmap threshold.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


@functools.lru_cache(maxsize=1)
def keep_freed_memory() -> bool:
    """Have this process (and the workers it forks) keep the memory it frees for reuse:
    glibc's allocator then serves arrays of up to 32 MB (its largest mmap threshold) from
    its heap and never gives freed heap memory back to the system. By default it maps an
    array of a few MB afresh and unmaps it when freed, so the next one faults its pages
    in again; a study chunk allocates such arrays (the metrics' temporaries, the operators'
    ring of observations) thousands of times, and on a VM a page fault is slow (first
    touch ran at ~0.4 GB/s here against ~27 GB/s for a copy). Changes no number, only
    where memory comes from. Returns False where the C library is not glibc (nothing
    changed)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the interpreter is linked with
    except (OSError, AttributeError, TypeError):
        return False
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024) == 1
    return bool(mallopt(_M_TRIM_THRESHOLD, 1 << 30) == 1 and ok)


def small_pages() -> bool:
    """Have this process (and the workers it forks) fault fresh memory in the system's small
    pages: numpy asks for transparent huge pages on every array of 4 MB or more (madvise),
    and where the kernel then compacts memory to find each one when first touched (its THP
    `defrag` setting `madvise`, this machine's) that costs more than it saves here. A study
    chunk touches its recording (`batch._Tape`, ~0.5 GB for 500 people in the objects world)
    once: with huge pages it spent ~1.35 s in the kernel, with small ones ~0.5 s (2-core AMD
    EPYC VM; the user time the same). Changes no number, only how memory is mapped. Returns
    False where this numpy has no such switch (nothing changed)."""
    core = getattr(np, "_core", None) or getattr(np, "core", None)
    switch = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
    if switch is None:
        return False
    switch(False)
    return True


#: A worker's queue of progress counts (trajectory-modes done) to the parent.
_QUEUE: SimpleQueue[int] | None = None


def _init_worker(queue: SimpleQueue[int]) -> None:
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
    ready: Callable[[int, StudyResult], None] | None = None,
) -> list[StudyResult]:
    """`simulate` for several studies at once, over one pool of workers.

    The studies' chunks are computed in the order of `cfgs`, and `ready(i, result)` is called
    in this process as soon as study i is complete, while the workers go on with the others
    (put a small study whose result is wanted early, e.g. to draw its figure, first).
    """
    keep_freed_memory()  # before the workers are forked: they inherit both
    small_pages()
    if workers <= 1:
        out = []
        for i, cfg in enumerate(cfgs):
            chunk = run_chunk(cfg, list(range(cfg.trajectories)), bar.advance if bar else None)
            out.append(merge(cfg, [chunk]))
            if ready is not None:
                ready(i, out[-1])
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
    queue: SimpleQueue[int] = ctx.SimpleQueue()

    def progress() -> None:
        while not queue.empty():
            done = queue.get()
            if bar:
                bar.advance(done)

    chunks: dict[int, ChunkResult] = {}
    results: dict[int, StudyResult] = {}
    with ctx.Pool(workers, initializer=_init_worker, initargs=(queue,)) as pool:
        # The pool hands the jobs out in this order.
        pending = [pool.apply_async(_work, ((cfg, idx),)) for _, cfg, idx in jobs]
        if meanwhile is not None:
            meanwhile()
        while len(results) < len(cfgs):
            waiting = [j for j in range(len(jobs)) if j not in chunks]
            if waiting:
                pending[waiting[0]].wait(0.1)
            for j in waiting:
                if pending[j].ready():
                    chunks[j] = pending[j].get()
            progress()
            for i, cfg in enumerate(cfgs):
                mine = [j for j, (k, _, _) in enumerate(jobs) if k == i]
                if i not in results and all(j in chunks for j in mine):
                    results[i] = merge(cfg, [chunks[j] for j in mine])
                    if ready is not None:
                        ready(i, results[i])
        progress()
    return [results[i] for i in range(len(cfgs))]
