"""The metric table: a metric defined and registered here, in a test file, reaches the study's
summary, report and tests, tuning (objective, trials, trials.csv, hold-out, reports, figures)
and replay's runs, aggregates and tests (`dsteleop replay`'s metrics.json) without an edit to
them; the table holds the paper's four metrics with their directions and scales."""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.cli.main import main
from dsteleop.app.replay.core import aggregate, session_summary
from dsteleop.app.session.trace import Trace
from dsteleop.app.study import batch, metric_table, report, results, summary
from dsteleop.app.study.metric_table import Metric, Trials
from dsteleop.app.study.planar import SimConfig
from dsteleop.app.tasks.executor import LocalExecutor
from dsteleop.app.tune import campaign
from dsteleop.app.tune.objective import Objective
from dsteleop.app.tune.trial import StudyBatch, study_task
from dsteleop.arbitration import Mode
from dsteleop.errors import ConfigError

# --- a metric of this file: the robot's mean translational output speed [m/s] -----------------


def speed_of_trials(t: Trials) -> NDArray[np.float64]:
    """Per trajectory, the mean |U_out| of the translation over the trial's ticks."""
    speed = np.linalg.norm(t.U_out[..., :3], axis=-1)
    ticks = t.acted.sum(1)
    return np.asarray(np.where(t.acted, speed, 0.0).sum(1) / np.maximum(ticks, 1))


def speed_of_run(trace: Trace) -> float:
    """The same over a replayed run's arbitrated ticks."""
    u = trace.step.U_out[trace.arbitrated, :3]
    return float(np.linalg.norm(u, axis=-1).mean())


SPEED = Metric(
    "speed",
    "output speed",
    "m/s",
    maximise=False,
    scale="linear",
    study=speed_of_trials,
    replay=speed_of_run,
)


@pytest.fixture
def speed() -> Iterator[Metric]:
    metric = metric_table.register(SPEED)
    try:
        yield metric
    finally:
        metric_table.unregister(metric.name)


ROOT = Path(__file__).resolve().parents[1]
CFG = SimConfig(trajectories=4, seed=2, modes=(Mode.S, Mode.DS), attempts=1, max_paths=0)


def test_the_table_holds_the_papers_metrics_in_table_is_order() -> None:
    assert metric_table.names() == ("success", "time_s", "cosine_distance", "agreement")
    m = {x.name: x for x in metric_table.table()}
    assert [m[n].maximise for n in metric_table.names()] == [True, False, False, True]
    assert [m[n].scale for n in metric_table.names()] == ["rate", "log", "linear", "linear"]
    assert m["time_s"].heading == "time [s]" and m["time_s"].test_key == "log_time"
    assert m["success"].summary_key == "success_rate" and m["success"].count_key == "successes"
    assert metric_table.tuning_key(m["cosine_distance"]) == "cosine_distance_per_action_mean"
    tuning = [x.name for x in metric_table.tuning_order()]
    assert tuning == ["success", "agreement", "cosine_distance", "time_s"]  # tuning's reports


def test_a_bad_or_repeated_metric_is_refused(speed: Metric) -> None:
    with pytest.raises(ConfigError, match="in the table already"):
        metric_table.register(SPEED)
    with pytest.raises(ConfigError, match="one of the paper's"):
        metric_table.unregister("agreement")
    with pytest.raises(ConfigError, match=r"unknown metric 'jerk' \(choose from .*speed"):
        metric_table.metric("jerk")
    with pytest.raises(ConfigError, match="scale"):
        Metric("x", "x", "", True, "median", speed_of_trials, speed_of_run)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="unknown metric"):
        Objective(metric="jerk")


def test_a_new_metric_reaches_the_study_its_summary_and_report(speed: Metric) -> None:
    res = results.merge(CFG, [batch.run_chunk(CFG, range(CFG.trajectories))])
    for mode in ("S", "DS"):
        v = res.modes[mode].values["speed"]
        assert v.shape == (CFG.trajectories,) and np.all((v > 0) & (v < 0.3))
    # Its value per trajectory is the metric's own: one trajectory alone, its every tick.
    one = batch.trace(CFG, 1, Mode.DS)
    assert res.modes["DS"].values["speed"][1] == pytest.approx(speed_of_run(one), rel=1e-9)
    s = summary.summarise(res)
    block = s["modes"]["DS"]["speed"]
    assert block["n"] == CFG.trajectories and block["geometric_mean"] > 0
    assert set(s["tests"]["S_vs_DS"]["speed"]) == {"two_sample_t", "paired_t"}
    md = report.markdown(s)
    assert "Ratio of Agreement | output speed [m/s] |" in md  # Table I's last column
    assert "| output speed | paired t |" in md
    line = report.brief(s, Path("x"), [], 0.0, 1)
    assert line["modes"]["DS"]["speed"] == block["geometric_mean"]
    assert "speed" in line["p_S_vs_DS"]


def test_a_new_metric_reaches_replay_runs_aggregates_and_tests(speed: Metric) -> None:
    entries = []
    for i in range(3):
        traces = [batch.trace(CFG, i, m) for m in (Mode.S, Mode.DS)]
        entry = session_summary(f"trajectory {i}", traces[0].recorded_s, traces)
        assert entry["modes"]["DS"]["speed"] == pytest.approx(speed_of_run(traces[1]))
        entries.append(entry)
    agg, tests = aggregate(entries, ["S", "DS"])
    values = [e["modes"]["DS"]["speed"] for e in entries]
    assert agg["DS"]["speed_arithmetic_mean"] == pytest.approx(float(np.mean(values)))
    assert agg["DS"]["speed"] == pytest.approx(math.exp(float(np.mean(np.log(values)))))
    assert len(agg["DS"]["speed_ci95"]) == 2
    assert "p_value" in tests["S_vs_DS"]["speed_ttest"]


def test_a_new_metric_reaches_the_replay_commands_metrics_json(
    speed: Metric, tmp_path: Path
) -> None:
    sessions = [str(ROOT / "recordings" / f"demo-{m}-spoon") for m in ("S", "DS")]
    argv = ["replay", *sessions, "--robot", "recorded", "--modes", "S,DS", "--no-plots"]
    assert main([*argv, "--workers", "1", "--out", str(tmp_path)]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    values = [e["modes"]["DS"]["speed"] for e in m["episodes"]]
    assert len(values) == 2 and all(0 < v < 0.3 for v in values)
    assert m["modes"]["DS"]["speed_arithmetic_mean"] == pytest.approx(float(np.mean(values)))
    assert "p_value" in m["tests"]["S_vs_DS"]["speed_ttest"]


def test_a_new_metric_can_be_tuned_on_and_reaches_every_tuning_output(
    speed: Metric, tmp_path: Path
) -> None:
    assert metric_table.tuning_order()[-1] is speed
    objective = Objective(metric="speed")
    assert objective.direction == "minimize"
    assert "minimise DS's output speed [m/s]" in objective.statement()
    m = study_task(StudyBatch(2, 0), {})
    assert m["study.DS.speed"] > 0 and math.isfinite(m["study.DS.speed_ci_half"])
    plan = campaign.Plan(
        given={"metric": "speed", "trajectories": 2, "space": ["kappa=log:2:8"]},
        trials=2,
        widen_edges=0,
        holdout_trajectories=2,
    )
    s = campaign.run(plan, tmp_path, LocalExecutor, False, time.monotonic())
    assert s["objective"]["metric"] == "speed" and s["best"] is not None
    assert s["best"]["value"] == s["best"]["metrics"]["study.DS.speed"]
    with (tmp_path / "trials.csv").open() as f:
        header = next(csv.reader(f))
    assert {"study.DS.speed", "study.DS.speed_ci_half", "study.S.speed"} <= set(header)
    h = s["holdout"]["study"]
    assert "speed" in h["best"]["DS"] and "p_value" in h["gain_DS"]["speed"]
    assert "speed_ci_half" in s["power"]
    md = (tmp_path / "summary.md").read_text()
    assert md.count("output speed [m/s]") >= 3  # the trial's, the held-out table's, the objective
    assert "| output speed |" in md  # the held-out gain's row
    assert (tmp_path / "sensitivity.png").stat().st_size > 0
    stored = json.loads((tmp_path / "summary.json").read_text())
    assert stored["best"]["metrics"]["study.DS.speed"] == s["best"]["metrics"]["study.DS.speed"]
    assert "speed" in campaign.brief(s)["holdout_gain_DS_over_base"]
    assert h["gain_DS"]["speed"]["n"] == 2 * SimConfig().attempts  # each person's runs, paired


def test_without_a_registered_metric_the_outputs_hold_only_the_papers() -> None:
    m = study_task(StudyBatch(2, 0), {})
    assert not any(k.endswith(".speed") for k in m)
    assert {k.split(".")[2] for k in m if k.count(".") == 2} == {
        "success", "successes", "n", "success_ci_low", "success_ci_high", "time_s",
        "cosine_distance", "cosine_distance_ci_half", "agreement", "agreement_ci_half",
        "gave_up",
    }  # fmt: skip
