"""`dsteleop tune`: the search space, the objective, reproducible samplers, the driver, and
small studies on a real local Ray cluster (a failing trial is recorded and the study goes on;
--resume continues; best.json goes through `dsteleop sim --config`)."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dsteleop.app.cli.main import main
from dsteleop.app.cli.options import add_loop_options, loop_options
from dsteleop.app.study.planar import SimConfig
from dsteleop.app.tasks.executor import LocalExecutor
from dsteleop.app.tune import driver, edges
from dsteleop.app.tune.objective import Objective, key
from dsteleop.app.tune.space import DEFAULT_SPACE, parse_dimension, parse_space
from dsteleop.app.tune.trial import StudyBatch, study_task
from dsteleop.arbitration import ArbitrationConfig, metrics
from dsteleop.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
SESSION = REPO / "recordings" / "demo-DS-spoon"  # S and DS both succeed when replayed
HELD_OUT_SESSION = REPO / "recordings" / "demo-manual-spoon"


# --- the search space -------------------------------------------------------------------------


def test_space_forms_and_grids() -> None:
    d = parse_dimension("kappa=log:1:40")
    assert (d.kind, d.low, d.high, d.log, d.integer) == ("log", 1.0, 40.0, True, False)
    assert d.grid(3) == pytest.approx((1.0, 6.32456, 40.0), rel=1e-5)
    w = parse_dimension("window=1:15")  # an integer field: an integer range
    assert (w.kind, w.integer) == ("int", True)
    assert w.grid(4) == (1, 6, 10, 15)
    assert parse_dimension("window=int:2:4").grid(5) == (2, 3, 4)
    b = parse_dimension("b=0.25:4")
    assert b.kind == "float" and b.grid(2) == (0.25, 4.0)
    c = parse_dimension("p=2,4,8")
    assert c.kind == "choice" and c.grid(2) == (2.0, 4.0, 8.0)
    assert [x.name for x in parse_space([])] == [
        "kappa", "p", "q", "b", "window", "DS.cap_translation", "DS.cap_rotation",
    ]  # fmt: skip
    assert [x.spec for x in parse_space([])] == list(DEFAULT_SPACE)


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("gain=1:2", "unknown parameter 'gain'"),
        ("kappa", "needs NAME=SPEC"),
        ("kappa=1", "malformed range"),
        ("kappa=lin:1:4", "malformed range"),
        ("kappa=4:1", "LOW < HIGH"),
        ("kappa=log:0:4", "LOW > 0"),
        ("kappa=1:x", "not a number: 'x'"),
        ("window=1.5:4", "integer range needs integer ends"),
        ("window=1,2.5", "window is an integer"),
        ("b=1,1", "two or more different values"),
    ],
)
def test_space_errors_name_what_is_wrong(item: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        parse_dimension(item)


def test_a_parameter_named_twice_is_an_error() -> None:
    with pytest.raises(ConfigError, match="kappa more than once"):
        parse_space(["kappa=1:2", "kappa=3:4"])


# --- edges of the best: found, widened, clipped to the domain ----------------------------------


def test_edges_are_widened_within_the_fields_domain_and_a_domain_bound_is_not() -> None:
    """The domains come from the validators (probed, not restated): scalar.cap in (0, 1] and
    scale in (0, 100] (check_range), p > 1, window >= 1."""
    base = ArbitrationConfig()
    space = parse_space(
        ["scalar.cap=0.9:1", "scalar.scale=log:0.2:50", "kappa=log:1:40", "p=log:1.5:12",
         "q=log:1.5:12", "window=int:1:15", "b=0.25:4"]
    )  # fmt: skip
    best = {"scalar.cap": 0.999, "scalar.scale": 49.0, "kappa": 39.0, "p": 1.51, "q": 4.0,
            "window": 1, "b": 2.0}  # fmt: skip
    widened, found = edges.widen(space, best, base)
    by_name = {e.name: e for e in found}
    assert set(by_name) == {"scalar.cap", "scalar.scale", "kappa", "p", "window"}  # q, b inside
    cap, window = by_name["scalar.cap"], by_name["window"]
    assert (cap.side, cap.status, cap.new_end) == ("high", "domain", None)  # 1 is cap's bound
    assert (window.side, window.status) == ("low", "domain")
    assert "at its domain bound" in cap.describe()
    scale, kappa, p = by_name["scalar.scale"], by_name["kappa"], by_name["p"]
    assert (scale.status, scale.new_end, scale.clipped) == ("widened", 100.0, True)  # not 200
    assert (kappa.status, kappa.new_end, kappa.clipped) == ("widened", 160.0, False)
    assert p.status == "widened" and p.clipped and p.new_end is not None
    assert 1.0 < p.new_end < 1.001  # p must be > 1
    assert [d.spec for d in widened] == [
        "scalar.cap=0.9:1", "scalar.scale=log:0.2:100", "kappa=log:1:160",
        f"p=log:{p.new_end:g}:12", "q=log:1.5:12", "window=int:1:15", "b=0.25:4",
    ]  # fmt: skip
    # A low cap widens by half the range's width; an edge is within 5 % of the width (log
    # width for a log range) of an end.
    (low,) = edges.widen(parse_space(["scalar.cap=0.9:1"]), {"scalar.cap": 0.904}, base)[1]
    assert (low.side, low.status, low.new_end) == ("low", "widened", 0.85)
    assert edges.widen(parse_space(["scalar.cap=0.9:1"]), {"scalar.cap": 0.906}, base)[1] == []
    (near,) = edges.edges_of(parse_space(["kappa=log:1:40"]), {"kappa": 40**0.96})
    assert near[1] == "high"
    assert edges.edges_of(parse_space(["kappa=log:1:40"]), {"kappa": 40**0.94}) == []


# --- the objective ---------------------------------------------------------------------------


def _metrics(ds_agree: float, s_succ: int, ds_succ: int) -> dict[str, float]:
    return {
        key("study", "DS", "agreement"): ds_agree,
        key("study", "S", "successes"): s_succ,
        key("study", "DS", "successes"): ds_succ,
    }


def test_objective_value_constraint_and_best() -> None:
    obj = Objective()
    assert obj.maximise and "subject to DS succeeding at least as often as S" in obj.statement()
    m = _metrics(0.8, 10, 9)
    assert obj.value(m) == 0.8 and obj.constraints(m) == [1.0] and not obj.feasible(m)
    assert Objective(constrained=False).feasible(m)
    assert not Objective(metric="cosine_distance").maximise

    def rec(n: int, value: float, cons: float) -> driver.TrialRecord:
        return driver.TrialRecord(n, "COMPLETE", {}, {}, value, (cons,), 1.0, 1.0)

    failed = driver.TrialRecord(9, "FAIL", {}, {}, None, (), 0.0, 0.0, "boom")
    recs = [rec(0, 0.7, 0.0), rec(1, 0.95, 1.0), rec(2, 0.9, -2.0), rec(3, 0.9, 0.0), failed]
    best = driver.best_of(recs, obj)
    assert best is not None and best.number == 2  # 1 is infeasible; 2 and 3 tie, 2 first
    assert driver.best_of([failed, rec(1, 0.95, 1.0)], obj) is None


def test_paired_difference_interval() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(1.0, 1.0, 200)
    b = a - 0.3 + rng.normal(0.0, 0.1, 200)
    b[5] = np.nan  # a pair with a missing value is dropped
    d = metrics.paired_difference(a, b)
    ok = np.isfinite(b)
    assert d.n == 199 and d.mean == pytest.approx(float(np.mean(a[ok] - b[ok])))
    assert d.ci_low < 0.3 < d.ci_high and d.ci_high - d.ci_low < 0.05
    t = metrics.paired_t_test(a[ok], b[ok])
    half = metrics.t_quantile(0.975, d.n - 1) * d.mean / t.t
    assert d.ci_high - d.mean == pytest.approx(half)


# --- the trial function and the driver, in this process ---------------------------------------


def test_the_trial_function_is_plain_python_without_ray() -> None:
    """The trial function runs alone (no cluster); no module but app/tasks/cluster.py imports
    Ray: the tune command's own modules, the executors' seam, the study and replay leave it
    unloaded."""
    code = (
        "import sys\n"
        "import dsteleop.app.cli.tune, dsteleop.app.tune.driver, dsteleop.app.tune.holdout\n"
        "import dsteleop.app.tasks.executor, dsteleop.app.tasks.progress\n"
        "import dsteleop.app.tune.report, dsteleop.app.tune.figures, dsteleop.app.replay.core\n"
        "from dsteleop.app.tune.trial import StudyBatch, study_task\n"
        "from dsteleop.arbitration import ArbitrationConfig\n"
        "m = study_task(StudyBatch(3, 0), ArbitrationConfig().to_dict())\n"
        "print(sorted(m)[0], 'ray' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.split() == ["study.DS.agreement", "False"]


def test_study_task_metrics_are_the_studys_own() -> None:
    m = study_task(StudyBatch(4, 0), ArbitrationConfig().to_dict())
    runs = 4 * SimConfig().runs  # each simulated person makes its runs (docs/sim.md)
    for mode in ("S", "DS"):
        assert m[key("study", mode, "n")] == runs
        assert 0 <= m[key("study", mode, "successes")] <= runs
        assert 0.0 <= m[key("study", mode, "agreement")] <= 1.0
        assert 0.0 <= m[key("study", mode, "cosine_distance")] <= 2.0
        assert 0.0 < m[key("study", mode, "time_s")] <= 60.0
    assert m["study.seconds"] > 0
    # The configuration reaches the trial: another kappa changes what DS does.
    other = study_task(StudyBatch(4, 0), ArbitrationConfig(kappa=30.0).to_dict())
    assert other[key("study", "DS", "agreement")] != m[key("study", "DS", "agreement")]


def _settings(sampler: str, seed: int, space: list[str], trajectories: int = 1) -> Any:
    return driver.TuneSettings(
        Objective(), parse_space(space), sampler=sampler, seed=seed,  # type: ignore[arg-type]
        grid_points=3, batch=StudyBatch(trajectories, 0),
    )  # fmt: skip


def _local_sequence(settings: Any, n: int, folder: Path) -> list[dict[str, Any]]:
    folder.mkdir()
    study = driver.open_study(folder, settings, resume=False)
    recs = driver.run_trials(study, settings, LocalExecutor(), n)
    assert [r.state for r in recs] == ["COMPLETE"] * n
    return [r.params for r in sorted(recs, key=lambda r: r.number)]


@pytest.mark.parametrize("sampler", ["grid", "random"])
def test_same_seed_and_sampler_give_the_same_trial_sequence(tmp_path: Path, sampler: str) -> None:
    space = ["kappa=log:1:40", "window=int:1:15"]
    first = _local_sequence(_settings(sampler, 7, space), 3, tmp_path / "a")
    again = _local_sequence(_settings(sampler, 7, space), 3, tmp_path / "b")
    other = _local_sequence(_settings(sampler, 8, space), 3, tmp_path / "c")
    assert first == again
    assert first != other
    assert len({tuple(p.values()) for p in first}) == 3  # no configuration twice
    if sampler == "grid":
        grid = {(k, w) for k in (1.0, 6.32456, 40.0) for w in (1, 8, 15)}
        assert {(round(p["kappa"], 5), p["window"]) for p in first} <= grid


def test_interrupted_trials_are_asked_again_on_resume(tmp_path: Path) -> None:
    settings = _settings("random", 0, ["kappa=log:1:40"])
    study = driver.open_study(tmp_path, settings, resume=False)
    lost = study.ask(driver.distributions(settings.space))  # a driver stopped while it ran
    study = driver.open_study(tmp_path, None, resume=True)
    assert driver.stored_settings(study) == settings
    assert driver.requeue_interrupted(study) == 1 and driver.counted(study) == 0
    (rec,) = driver.run_trials(study, settings, LocalExecutor(), 1)
    assert rec.state == "COMPLETE" and rec.params == lost.params and rec.number == 1
    assert [r.number for r in driver.records(study, settings.space)] == [1]


def test_a_raising_trial_is_recorded_and_the_study_goes_on(tmp_path: Path) -> None:
    """In this process: p = 0.8 is outside p's domain, so those trials raise (ConfigError)."""
    settings = _settings("grid", 0, ["p=0.8,4", "window=3,5"])
    study = driver.open_study(tmp_path, settings, resume=False)
    recs = driver.run_trials(study, settings, LocalExecutor(), 4)
    by_p = {(r.params["p"], r.params["window"]): r for r in recs}
    assert len(by_p) == 4
    for (p, _), r in by_p.items():
        if p == 0.8:
            assert r.state == "FAIL" and r.value is None
            assert r.error == "ConfigError: p must be > 1 (beta prime needs a mode), got 0.8"
        else:
            assert r.state == "COMPLETE" and r.value is not None and 0 <= r.value <= 1


# --- the command: bad input --------------------------------------------------------------------


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])  # closed again when the block ends


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--space", "gain=1:2"], "unknown parameter 'gain'"),
        (["--space", "kappa=4:1"], "the range needs LOW < HIGH"),
        (["--space", "v_max_mps=0.1:0.3"], "would tune the person too"),
        (["--objective", "sessions"], "--objective sessions needs --sessions"),
        (["--objective", "best"], "unknown objective 'best'"),
        (["--sampler", "cmaes"], "unknown sampler 'cmaes'"),
        (["--sessions", "/nonexistent/session"], "--sessions: not found"),
        (["--trials", "0"], "--trials must be >= 1"),
        (["--address", "ray://nohost"], "expected ray://HOST:PORT, HOST:PORT or auto"),
        (["--address", "ray://127.0.0.1:PORT"], "cannot reach a Ray cluster there"),
        (["--holdout-seed", "0"], "is the tuning trajectories' seed"),
        (["--resume"], "--resume: no tuning study"),
        (["--goal-sigma", "-1"], "goal_sigma_m must be a number >= 0"),
        (["--widen-edges", "-1"], "--widen-edges must be >= 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    args = [a.replace("PORT", str(_closed_port())) for a in args]
    code = main(["tune", "--no-progress", "--trials", "2", "--out", str(tmp_path / "o"), *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("dsteleop tune: error:") and message in err[0]
    assert "ray" not in sys.modules  # nothing started


def test_a_budget_is_trials_or_trials_per_parameter_not_both(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = ["tune", "--no-progress", "--out", str(tmp_path / "o")]
    assert main([*out, "--trials-per-param", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["dsteleop tune: error: --trials-per-param must be >= 1, got 0"]
    with pytest.raises(SystemExit) as exc:  # argparse's own one line
        main([*out, "--trials", "2", "--trials-per-param", "2"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--trials-per-param: not allowed with argument --trials" in err[0]


def test_bad_input_in_a_subprocess_has_no_traceback(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "tune", "--space", "window=0.5:3",
         "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "dsteleop tune: error: --space window=0.5:3: an integer range needs integer ends"
    ]


# --- the command on a real local Ray cluster -------------------------------------------------


def tune(
    out: Path, home: Path, *args: str, trace: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """`dsteleop tune` in a subprocess with its own HOME (to see what it writes there); with
    `trace`, under strace, every process's connect() calls logged there."""
    home.mkdir(exist_ok=True)
    env = {**os.environ, "HOME": str(home)}
    strace = ["strace", "-f", "-qq", "-e", "trace=connect", "-o", str(trace)] if trace else []
    return subprocess.run(
        [*strace, sys.executable, "-m", "dsteleop.app.cli.main", "tune", "--no-progress",
         "--out", str(out), *args],
        capture_output=True, text=True, timeout=600, check=False, env=env,
    )  # fmt: skip


def remote_addresses(trace: Path) -> set[str]:
    """The IP addresses that the traced processes connected to, other than loopback."""
    found = set(re.findall(r'inet_addr\("([0-9.]+)"\)', trace.read_text()))
    found |= set(re.findall(r'inet_pton\(AF_INET6, "([^"]+)"', trace.read_text()))
    return {a for a in found if a not in ("127.0.0.1", "::1", "::ffff:127.0.0.1")}


def read_trials(out: Path) -> list[dict[str, str]]:
    with (out / "trials.csv").open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_a_study_on_a_local_ray_cluster_records_failures_and_resumes(tmp_path: Path) -> None:
    """A 2 x 2 grid over p (0.8 is outside its domain: those trials raise in the workers) and
    the window, on the study and a replayed session: half the grid first, then --resume
    finishes it (the sessions reaching the workers by path, then through the object store).
    """
    out, home = tmp_path / "study", tmp_path / "home"
    # Without the constraint every complete trial can be the best: best.json always exists
    # (whether DS meets S's successes on 3 trajectories is not this test's question).
    common = ["--sampler", "grid", "--space", "p=0.8,4", "--space", "window=3,5", "--seed", "1",
              "--no-constraint", "--trajectories", "3", "--holdout-trajectories", "8",
              "--workers", "2"]  # fmt: skip
    # Traced where strace exists: the local cluster connects to nothing but this machine.
    trace = tmp_path / "connect.trace" if shutil.which("strace") else None
    first = tune(
        out, home, "--objective", "both", "--sessions", str(SESSION), "--trials", "2", *common,
        trace=trace,
    )  # fmt: skip
    assert first.returncode == 0, first.stderr
    if trace is not None:
        assert "connect(" in trace.read_text()  # the trace saw the cluster's connections
        assert remote_addresses(trace) == set()
    # Nothing a user must read: only log lines of the command (and of matplotlib, which logs
    # building its font cache in a new home folder), no output of Ray; and Ray writes nothing
    # to the home folder (its token lives in the environment).
    own = re.compile(r"^\d{4}-\d\d-\d\d [\d:,]+ (INFO|WARNING) (dsteleop|matplotlib)\.")
    assert all(own.match(ln) for ln in first.stderr.splitlines() if ln.strip()), first.stderr
    assert not (home / ".ray").exists()
    line = json.loads(first.stdout)  # one JSON line
    assert first.stdout.count("\n") == 1
    assert line["cluster"]["cluster"] == "local" and line["cluster"]["cpus"] == 2
    assert line["trials"]["finished"] == 2 and line["timing"]["trials_run"] == 2
    first_rows = read_trials(out)
    assert [r["number"] for r in first_rows] == ["0", "1"]

    # --resume: the stored settings (a differing one is refused), two more trials.
    refused = tune(out, home, "--resume", "--trials", "4", "--space", "p=2,4")
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1
    assert "the study was made with space" in refused.stderr
    again = tune(
        out, home, "--resume", "--trials", "4", "--sessions-via", "store",
        "--holdout-trajectories", "8", "--holdout-sessions", str(HELD_OUT_SESSION),
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    summary = json.loads(again.stdout)
    assert summary["timing"]["trials_run"] == 2 and summary["trials"]["finished"] == 4
    rows = read_trials(out)
    assert [r["number"] for r in rows] == ["0", "1", "2", "3"]
    assert rows[:2] == first_rows  # the first run's trials, as they were
    # The same grid sequence as the in-process driver with the same seed.
    settings = driver.stored_settings(driver.open_study(out, None, resume=True))
    grid_sampler = driver.make_sampler(settings, 0)
    expected = [dict(zip(sorted(["p", "window"]), g)) for g in grid_sampler._all_grids]  # type: ignore[attr-defined]
    assert [{"p": float(r["p"]), "window": int(r["window"])} for r in rows] == expected
    # The raising trials are recorded as failed, the others complete with every metric.
    for r in rows:
        if float(r["p"]) == 0.8:
            assert r["state"] == "FAIL" and r["value"] == ""
            assert r["error"] == "ConfigError: p must be > 1 (beta prime needs a mode), got 0.8"
        else:
            assert r["state"] == "COMPLETE" and r["error"] == ""
            for source in ("study", "sessions"):
                for mode in ("S", "DS"):
                    assert 0.0 <= float(r[f"{source}.{mode}.agreement"]) <= 1.0
            assert float(r["sessions.DS.n"]) == 1
            assert float(r["study.DS.n"]) == 3 * SimConfig().runs
            assert float(r["value"]) == pytest.approx(
                (float(r["study.DS.agreement"]) + float(r["sessions.DS.agreement"])) / 2
            )
    files = set(summary["files"])
    assert {"trials.csv", "sensitivity.png", "heatmap.png", "summary.md"} <= files
    md = (out / "summary.md").read_text()
    assert "ConfigError: p must be > 1" in md and "## Held-out evaluation" in md
    assert "Held-out sessions (1)" in md
    assert summary["best"]["number"] in (int(r["number"]) for r in rows if r["state"] == "COMPLETE")
    assert summary["holdout_gain_DS_over_base"]["trajectories"] == 8
    check_best_json_round_trips_through_sim(out, tmp_path)


def check_best_json_round_trips_through_sim(out: Path, tmp_path: Path) -> None:
    best = json.loads((out / "best.json").read_text())
    assert set(best) == {"schema", "arbitration", "objective", "world", "note"}
    assert set(best["arbitration"]) == set(ArbitrationConfig().to_dict())
    sim_out = tmp_path / "sim"
    code = main(["sim", "--no-progress", "--no-figures", "--trajectories", "10",
                 "--config", str(out / "best.json"), "--out", str(sim_out)])  # fmt: skip
    assert code == 0
    used = json.loads((sim_out / "summary.json").read_text())["config"]["arbitration"]
    assert used == best["arbitration"]
    # run and serve read it through the same loop options.
    parser = argparse.ArgumentParser()
    add_loop_options(parser, "demo", "record a session into DIR")
    loop = loop_options(parser.parse_args(["--config", str(out / "best.json")])).loop
    assert loop.arbitration.to_dict() == best["arbitration"]
    assert not math.isnan(best["objective"]["value"])


@pytest.mark.slow
def test_quick_bench_runs_the_same_trials_alone_and_on_1_and_2_ray_workers() -> None:
    """The figures are docs/benchmarks.md's, never asserted; the bench itself checks that every Ray
    run evaluated the configurations the trial function ran alone."""
    r = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", "bench", "--only", "tune", "--quick"],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    tune_ = out["tune"]
    assert tune_["trials"] == 2 and len(tune_["configurations"]) == 2
    for name in ("alone", "ray_1_worker", "ray_2_workers"):
        assert tune_[name]["trials_per_minute"] > 0
    for name in ("ray_1_worker", "ray_2_workers"):
        assert tune_[name]["cluster_start_s"] > 0
        assert tune_[name]["trials_per_minute_with_start"] < tune_[name]["trials_per_minute"]
    assert out["machine"]["cpu"] and out["machine_after"]["load_average"]


@pytest.mark.slow
def test_tuning_in_another_world_widens_an_edge_with_a_budget_per_parameter(
    tmp_path: Path,
) -> None:
    """The scalar's cap over 0.9:1 (a grid of its two ends) in a world without goal noise:
    the trials score that world (S succeeds otherwise than in the default one, on the same
    trajectories), the best lands on the low edge, so the range is widened there and the
    campaign run again with the same budget (2 trials per parameter), twice; each round is
    stored apart, --resume continues them all and refuses another world."""
    out, home = tmp_path / "study", tmp_path / "home"
    args = ["--mode", "scalar", "--space", "scalar.cap=0.9:1", "--sampler", "grid",
            "--grid-points", "2", "--trials-per-param", "2", "--trajectories", "20",
            "--no-constraint", "--holdout-trajectories", "10", "--workers", "2",
            "--no-figures"]  # fmt: skip
    r = tune(out, home, *args, "--goal-sigma", "0")
    assert r.returncode == 0, r.stderr
    line = json.loads(r.stdout)
    assert line["world"] == "the study's world with world.goal_sigma_m = 0.0"
    assert line["budget"].startswith("--trials-per-param 2") and line["rounds"] == 3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["settings"]["world"] == {"world": {"goal_sigma_m": 0.0}}
    assert summary["budget"] == {**summary["budget"], "per_param": 2, "params": 1, "trials": 2}
    rounds = summary["rounds"]
    assert [x["space"] for x in rounds] == [
        ["scalar.cap=0.9:1"],
        ["scalar.cap=0.85:1"],
        ["scalar.cap=0.775:1"],
    ]
    assert [x["trials"] for x in rounds] == [2, 2, 2]
    # Each round's best lies on its low edge.
    assert [x["best"]["params"]["scalar.cap"] for x in rounds] == [0.9, 0.85, 0.775]
    assert [e["status"] for x in rounds for e in x["edges"]] == ["widened", "widened", "rounds"]
    assert summary["edges"] == rounds[-1]["edges"] and line["edges"][0]["status"] == "rounds"
    md = (out / "summary.md").read_text()
    assert "world.goal_sigma_m = 0.0" in md and "## Edges of the search space" in md
    assert "the widening rounds (--widen-edges) were used up" in md
    assert "2 trials per searched parameter x 1 = 2" in md
    for name in ("trials-round-0.csv", "widen-1/trials.csv", "widen-2/study.journal"):
        assert (out / name).exists()
    best = json.loads((out / "best.json").read_text())
    assert best["world"]["overrides"] == {"world": {"goal_sigma_m": 0.0}}
    assert best["arbitration"]["scalar.cap"] == 0.775
    # The world reached the trials: the same trajectories in the default world differ.
    default = study_task(StudyBatch(20, 0, "scalar"), ArbitrationConfig().to_dict())
    row = read_trials(out)[0]
    assert float(row["study.S.successes"]) != default[key("study", "S", "successes")]
    assert summary["holdout"]["study"]["trajectories"] == 10

    refused = tune(out, home, "--resume", "--goal-sigma", "0.01", "--trials-per-param", "2")
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1
    assert "the study was made with world" in refused.stderr
    again = tune(out, home, "--resume", "--trials-per-param", "2", "--holdout-trajectories", "0",
                 "--no-figures", "--workers", "2")  # fmt: skip
    assert again.returncode == 0, again.stderr
    resumed = json.loads(again.stdout)
    assert resumed["timing"]["trials_run"] == 0 and resumed["rounds"] == 3
    assert resumed["best"] == line["best"]
