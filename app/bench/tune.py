"""`dsteleop bench --only tune`: trials per minute of `dsteleop tune`'s study trial, alone and
as Ray tasks on a local cluster of 1 and of 2 workers, so that Ray's overhead shows.

The same K configurations (the random sampler's first K draws with seed 0 over the default
search space) on the same tuning batch (the command's default of 400 trajectories; `--quick`:
40 trajectories and K = 2), three ways:

    alone           the trial function (`app.tune.trial.study_task`) in a plain loop in this
                    process: no Optuna, no Ray
    ray_1_worker    the tune driver on a fresh local Ray cluster of 1 CPU: Optuna asks, Ray
    ray_2_workers   runs the tasks, results are told as they arrive; of 2 CPUs

`trials_per_minute` is K over the trials' wall time; a cluster's start (`cluster_start_s`,
ray.init until it is ready) is apart, and `trials_per_minute_with_start` includes it. A
trial's cost depends on its configuration (it lasts until the simulated people are done), so
only runs over the same configurations compare. The machine's CPU model and load are beside
the figures (`machine`, `machine_after`).
"""

from __future__ import annotations

import logging
import time
from typing import Any

log = logging.getLogger(__name__)


def run(quick: bool) -> dict[str, Any]:
    from dsteleop.app.tasks.cluster import RayExecutor
    from dsteleop.app.tune import driver
    from dsteleop.app.tune.objective import Objective
    from dsteleop.app.tune.space import as_values, parse_space
    from dsteleop.app.tune.trial import StudyBatch, study_task

    k = 2 if quick else 8
    batch = StudyBatch(40 if quick else 400, 0)
    settings = driver.TuneSettings(
        Objective(), parse_space([]), sampler="random", seed=0, batch=batch
    )
    asker = driver.memory_study(settings)
    asker.sampler = driver.make_sampler(settings, 0)
    configs = []
    for _ in range(k):
        trial = asker.ask(driver.distributions(settings.space))
        configs.append(as_values(trial.params, settings.space))
        asker.tell(trial, 0.0)

    log.info("bench tune: %d trials of %d trajectories alone", k, batch.trajectories)
    t0, c0 = time.perf_counter(), time.process_time()
    for params in configs:
        study_task(batch, settings.arbitration(params))
    alone_s, alone_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    out: dict[str, Any] = {
        "trials": k,
        "trajectories_per_trial": batch.trajectories,
        "configurations": configs,
        "alone": {
            "trials_per_minute": round(60.0 * k / alone_s, 3),
            "seconds_per_trial": round(alone_s / k, 3),
            "cpu_seconds_per_trial": round(alone_cpu_s / k, 3),
        },
    }
    for workers in (1, 2):
        log.info("bench tune: %d trials on a local Ray cluster of %d CPU(s)", k, workers)
        t0 = time.perf_counter()
        with RayExecutor(workers=workers) as executor:
            start_s = time.perf_counter() - t0
            study = driver.memory_study(settings)
            t1 = time.perf_counter()
            recs = driver.run_trials(study, settings, executor, k)
            trials_s = time.perf_counter() - t1
        asked = [r.params for r in sorted(recs, key=lambda r: r.number)]
        if asked != configs or any(r.state != "COMPLETE" for r in recs):
            raise RuntimeError("bench tune: the Ray run did not evaluate the same configurations")
        name = "ray_1_worker" if workers == 1 else f"ray_{workers}_workers"
        out[name] = {
            "cluster_start_s": round(start_s, 2),
            "trials_per_minute": round(60.0 * k / trials_s, 3),
            "trials_per_minute_with_start": round(60.0 * k / (trials_s + start_s), 3),
            "seconds": round(trials_s, 2),
        }
    return {"tune": out}
