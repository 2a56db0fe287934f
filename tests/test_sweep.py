"""`dsteleop sim --sweep`: the grid, a real local Ray cluster of 2 workers, resuming, pairing,
McNemar's test of each cell against scipy, bad grids."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats

from dsteleop.app.cli.main import main
from dsteleop.app.operator.world import Impairments
from dsteleop.app.study import planar, sweep
from dsteleop.arbitration import Mode
from dsteleop.errors import FormatError, InputError

# --- the grid ---------------------------------------------------------------------------------


def test_default_grid_has_three_levels_per_axis_around_the_worlds_defaults() -> None:
    g = sweep.default_grid()
    assert len(g.cells()) == 27
    w = Impairments()
    for axis, name in sweep.AXES.items():
        levels = g.levels[axis]
        assert len(levels) == 3 and levels[0] == 0.0 and levels[1] < levels[2]
        d = getattr(w, name)
        if d > 0:
            assert levels == (0.0, d, 2 * d)
    cells = g.cells()
    assert len(set(cells)) == 27 and cells[0] == (0.0, 0.0, 0.0)


def test_parse_grid_overrides_given_axes_only() -> None:
    g = sweep.parse_grid(["goal=0,0.01", "delay=0.3"])
    assert g.levels["goal"] == (0.0, 0.01) and g.levels["delay"] == (0.3,)
    assert g.levels["depth"] == sweep.default_levels("depth")
    assert len(g.cells()) == 2 * 1 * 3
    assert sweep.cell_name((0.02, 0.15, 0.0)) == "goal0.02_delay0.15_depth0"


def test_with_world_sets_the_cell_and_keeps_the_rest() -> None:
    cfg = planar.SimConfig(trajectories=3, world=Impairments(lateral_sigma_m=0.005))
    c = sweep.with_world(cfg, (0.04, 0.1, 0.003))
    assert c.world == Impairments(
        goal_sigma_m=0.04, delay_s=0.1, depth_sigma_m=0.003, lateral_sigma_m=0.005
    )
    # The robot's goal noise follows the goal axis (the study's draws).
    i = 1
    g0 = planar.sample_closed_trial(sweep.with_world(cfg, (0.0, 0.0, 0.0)), i).robot_goal
    g4 = planar.sample_closed_trial(c, i).robot_goal
    np.testing.assert_allclose(g0[:2], cfg.handle_xy_m)
    assert np.linalg.norm(g4[:2] - np.asarray(cfg.handle_xy_m)) > 0


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (["goal=a"], "'a' is not a number"),
        (["noise=0,1"], "AXIS one of goal, delay, depth"),
        (["goal"], "expected AXIS=V1,V2"),
        (["delay=0,-0.1"], "finite and >= 0"),
        (["depth=0,0"], "given twice"),
        (["goal=0", "goal=0.1"], "axis 'goal' given twice"),
        (["goal="], "'' is not a number"),
        (["goal=0", "--trajectories", "1"], "--sweep needs --trajectories >= 2"),
        (["goal=0", "--resume", "--address", "nowhere"], "expected ray://HOST:PORT"),
    ],
)
def test_a_grid_that_does_not_parse_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], spec: list[str], message: str
) -> None:
    code = main(["sim", "--no-progress", "--out", str(tmp_path / "o"), "--sweep", *spec])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("dsteleop sim: error:") and message in err[0]
    assert not (tmp_path / "o" / "cells").exists()


def test_bad_grid_in_a_subprocess_has_no_traceback(tmp_path: Path) -> None:
    args = ["sim", "--out", str(tmp_path), "--sweep", "delay=soon"]
    proc = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", *args],
        capture_output=True,
        check=False,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "dsteleop sim: error: --sweep 'delay=soon': 'soon' is not a number"
    ]


def test_resume_and_address_need_a_sweep(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sim", "--out", str(tmp_path), "--resume"]) == 2
    assert "go with --sweep" in capsys.readouterr().err


# --- one cell's statistics ----------------------------------------------------------------------


def _cell(success: dict[str, list[int]]) -> dict[str, Any]:
    n = len(next(iter(success.values())))
    return {
        "cell": {"goal_sigma_m": 0.0, "delay_s": 0.0, "depth_sigma_m": 0.0},
        "modes": {
            m: {"success": s, "time_s": [5.0 + k for k in range(n)], "censored": [0] * n}
            for m, s in success.items()
        },
    }


def test_cell_verdicts_can_come_out_either_way() -> None:
    n = 30
    win = sweep.summarise_cell(_cell({"S": [0] * n, "DS": [1] * n, "manual": [1] * n}))
    x = win["ds_minus_best_scalar"]
    assert x["versus"] == "S" and x["verdict"] == "DS wins" and x["success_difference"] == 1.0
    lose = sweep.summarise_cell(_cell({"S": [1] * n, "DS": [0] * n}))
    assert lose["ds_minus_best_scalar"]["verdict"] == "DS loses"
    assert lose["best_mode"] == "S"
    # Discordant both ways, balanced: a tie, whatever the marginal rates.
    tie = sweep.summarise_cell(_cell({"S": [1, 0] * (n // 2), "DS": [0, 1] * (n // 2)}))
    assert tie["ds_minus_best_scalar"]["verdict"] == "tie"
    assert tie["ds_minus_best_scalar"]["mcnemar"]["p_exact"] == 1.0
    # The best scalar is the best single-alpha mode present (the scalar baseline too).
    two = sweep.summarise_cell(_cell({"S": [0] * n, "scalar": [1] * n, "DS": [1] * n}))
    assert two["ds_minus_best_scalar"]["versus"] == "scalar"
    assert two["ds_minus_best_scalar"]["verdict"] == "tie"


# --- a real sweep on a local Ray cluster of 2 workers --------------------------------------------


def _sweep(
    out: Path, *extra: str, grid: tuple[str, ...] = ("goal=0,0.04", "delay=0,0.15")
) -> subprocess.CompletedProcess[str]:
    """The sweep command in a process of its own, as a user runs it (its Ray cluster and
    its imports do not outlive it into the tests that follow)."""
    args = [
        "sim", "--no-progress", "--out", str(out), "--trajectories", "6", "--seed", "4",
        "--modes", "S,DS,manual", "--workers", "2", "--sweep", *grid, "depth=0", *extra,
    ]  # fmt: skip
    return subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", *args],
        capture_output=True, text=True, timeout=900, check=False,
    )  # fmt: skip


@pytest.mark.slow
def test_sweep_on_a_local_two_worker_cluster_writes_resumes_and_pairs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sweep"
    run = _sweep(out)
    assert run.returncode == 0, run.stderr
    printed = json.loads(run.stdout)
    assert printed["cells"] == 4 and printed["computed"] == 4 and printed["resumed"] == 0
    assert printed["cluster"]["cluster"] == "local" and printed["cluster"]["cpus"] == 2
    assert printed["files"] == ["sweep.json", "sweep.md", "sweep.png"]
    s = json.loads((out / "sweep.json").read_text())
    assert s["modes"] == ["S", "DS", "manual"] and s["scalar_modes"] == ["S"]
    assert len(s["cells"]) == 4 and sum(s["counts"].values()) == 4
    png = (out / "sweep.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    md = (out / "sweep.md").read_text()
    assert "| goal sigma [m] | delay [s] | depth sigma [m] | S | DS | manual | best |" in md
    assert md.count("\n| 0") + md.count("\n| 0.04") >= 4

    cells = {tuple(c["cell"].values()): c for c in s["cells"]}
    raw = {p.stem: json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))}
    assert len(raw) == 4
    for c in s["cells"]:
        data = raw[c["name"]]
        # McNemar's exact test of DS vs the best scalar, against scipy on the stored outcomes.
        ds = np.array(data["modes"]["DS"]["success"], dtype=bool)
        sv = np.array(data["modes"]["S"]["success"], dtype=bool)
        b, k = int(np.sum(ds & ~sv)), int(np.sum(~ds & sv))
        x = c["ds_minus_best_scalar"]
        ref = 1.0 if b + k == 0 else stats.binomtest(min(b, k), b + k, 0.5).pvalue
        assert x["mcnemar"]["p_exact"] == pytest.approx(ref, rel=1e-9)
        assert (x["mcnemar"]["first_only"], x["mcnemar"]["second_only"]) == (b, k)
    # The goal axis works: with no goal noise S parks the robot on the handle and succeeds
    # (nearly) every run; with 4 cm per axis it misses most.
    runs = 6 * planar.SimConfig().attempts  # each of the 6 people makes `attempts` runs
    for delay in (0.0, 0.15):
        clean = cells[(0.0, delay, 0.0)]["modes"]["S"]["successes"]
        noisy = cells[(0.04, delay, 0.0)]["modes"]["S"]["successes"]
        assert clean >= 0.8 * runs and noisy < clean
    # Paired: the goal noise changes only the robot's goal, so manual (alpha = 0) gives the
    # same trials in every goal level, and a cell run alone gives the sweep's results.
    m0 = raw["goal0_delay0_depth0"]["modes"]["manual"]
    m4 = raw["goal0.04_delay0_depth0"]["modes"]["manual"]
    assert m0["success"] == m4["success"]
    np.testing.assert_allclose(m0["time_s"], m4["time_s"], rtol=0, atol=1e-9)
    cfg = planar.SimConfig(trajectories=6, seed=4, modes=(Mode.S, Mode.DS, Mode.MANUAL))
    alone = sweep.cell_task(cfg, (0.04, 0.0, 0.0))
    for mode in ("S", "DS", "manual"):
        got = raw["goal0.04_delay0_depth0"]["modes"][mode]
        assert alone["modes"][mode]["success"] == got["success"]
        np.testing.assert_allclose(alone["modes"][mode]["time_s"], got["time_s"], atol=1e-9)

    # Resume: a larger grid reuses the finished cells (their files untouched) and computes
    # only the new ones.
    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "cells").iterdir()}
    run = _sweep(out, "--resume", grid=("goal=0,0.02,0.04", "delay=0,0.15"))
    assert run.returncode == 0, run.stderr
    printed = json.loads(run.stdout)
    assert printed["cells"] == 6 and printed["computed"] == 2 and printed["resumed"] == 4
    for p in (out / "cells").iterdir():
        if p.name in before:
            assert (p.stat().st_mtime_ns, p.read_bytes()) == before[p.name]
    assert len(list((out / "cells").glob("*.json"))) == 6
    # Everything done: a resume starts no cluster and computes nothing.
    run = _sweep(out, "--resume", grid=("goal=0,0.02,0.04", "delay=0,0.15"))
    assert run.returncode == 0, run.stderr
    printed = json.loads(run.stdout)
    assert printed["computed"] == 0 and printed["resumed"] == 6 and printed["cluster"] is None

    # Without --resume the folder is not overwritten; other settings are refused on resume.
    run = _sweep(out)
    err = run.stderr.strip().splitlines()
    assert run.returncode == 2
    assert len(err) == 1 and "holds a sweep already" in err[0]
    code = main(
        ["sim", "--no-progress", "--out", str(out), "--trajectories", "7", "--seed", "4",
         "--modes", "S,DS,manual", "--sweep", "goal=0", "delay=0", "depth=0", "--resume"]
    )  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "other settings" in err[0]


def test_the_sweep_module_and_a_cell_leave_ray_unloaded() -> None:
    """Only app/tasks/cluster.py imports Ray: a cell computes in plain Python."""
    code = (
        "import sys\n"
        "import dsteleop.app.cli.sim\n"
        "from dsteleop.app.study import sweep, planar\n"
        "from dsteleop.arbitration import Mode\n"
        "cfg = planar.SimConfig(trajectories=2, modes=(Mode.S, Mode.DS))\n"
        "r = sweep.cell_task(cfg, (0.0, 0.0, 0.0))\n"
        "print(sorted(r['modes']), 'ray' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True
    )
    assert out.stdout.split() == ["['DS',", "'S']", "False"]


@pytest.mark.slow
def test_sweep_on_a_cluster_the_user_started_runs_and_resumes(tmp_path: Path) -> None:
    """`--address HOST:PORT`: the cells go to a cluster started apart (`ray start --head`,
    on loopback), and `--resume` there computes nothing again."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ray = Path(sys.executable).parent / "ray"
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    head = [
        str(ray), "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(port),
        "--num-cpus", "2", "--include-dashboard", "false", "--disable-usage-stats",
    ]  # fmt: skip
    started = subprocess.run(head, capture_output=True, text=True, env=env, timeout=180)
    try:
        assert started.returncode == 0, started.stderr[-2000:]
        out = tmp_path / "sweep"
        args = [
            sys.executable, "-m", "dsteleop.app.cli.main", "sim", "--no-progress", "--out",
            str(out), "--trajectories", "6", "--seed", "4", "--modes", "S,DS,manual",
            "--address", f"127.0.0.1:{port}", "--sweep", "goal=0,0.04", "delay=0", "depth=0",
        ]  # fmt: skip
        first = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
        assert first.returncode == 0, first.stderr[-2000:]
        a = json.loads(first.stdout)
        assert a["cluster"]["cluster"] == f"127.0.0.1:{port}" and a["cluster"]["nodes"] == 1
        assert (a["cells"], a["computed"], a["resumed"], a["failed"]) == (2, 2, 0, 0)
        again = subprocess.run(
            [*args, "--resume"], capture_output=True, text=True, env=env, timeout=600
        )
        assert again.returncode == 0, again.stderr[-2000:]
        b = json.loads(again.stdout)
        assert (b["computed"], b["resumed"]) == (0, 2) and b["counts"] == a["counts"]
    finally:
        subprocess.run([str(ray), "stop", "--force"], capture_output=True, env=env, timeout=120)


# --- the axes design and a configuration per cell -----------------------------------------------


def test_axes_design_varies_one_impairment_at_a_time_from_the_worlds_centre() -> None:
    g = sweep.default_grid()
    mid = sweep.centre(planar.SimConfig())
    w = Impairments()
    assert mid == (w.goal_sigma_m, w.delay_s, w.depth_sigma_m)
    cells = sweep.design_cells(g, "axes", mid)
    assert len(cells) == 7 and mid in cells
    assert all(sum(a != b for a, b in zip(c, mid, strict=True)) <= 1 for c in cells)
    # Each other level of each axis once, in the grid's order.
    for k, axis in enumerate(sweep.AXES):
        assert sorted(c[k] for c in cells if c[k] != mid[k]) == [
            v for v in g.levels[axis] if v != mid[k]
        ]
    assert cells == [c for c in g.cells() if c in cells]
    assert sweep.design_cells(g, "grid", mid) == g.cells()
    # The centre follows the world the study is given.
    moved = sweep.centre(planar.SimConfig(world=Impairments(delay_s=0.0)))
    assert moved[1] == 0.0 and len(sweep.design_cells(g, "axes", moved)) == 7


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--sweep-design", "axes", "--goal-sigma", "0.03"], "the world's goal 0.03 (the centre)"),
        (
            ["--cell-configs", "{tmp}", "--config", "tests/golden/tune-best/both.json"],
            "mutually exclusive",
        ),
        (["--cell-configs", "{tmp}/none"], "--cell-configs: not a folder"),
        (["--cell-configs", "{tmp}"], "no goal0_delay0.2_depth0.015.json (7 of 7 cells"),
        (["--cell-configs", "{tmp}", "--sweep-design", "grid"], "(27 of 27 cells"),
    ],
)
def test_bad_design_or_cell_configs_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    args = [a.replace("{tmp}", str(tmp_path)) for a in extra]
    if "grid" not in args and "--goal-sigma" not in args:
        args = ["--sweep-design", "axes", *args]
    code = main(["sim", "--no-progress", "--out", str(tmp_path / "o"), "--sweep", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("dsteleop sim: error:") and message in err[0]
    assert not (tmp_path / "o").exists()


def test_design_and_cell_configs_need_a_sweep(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sim", "--out", str(tmp_path), "--sweep-design", "axes"]) == 2
    assert main(["sim", "--out", str(tmp_path), "--cell-configs", str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("go with --sweep") == 2


def test_a_cell_config_that_is_not_a_configuration_names_its_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    grid = ["goal=0.02", "delay=0.2", "depth=0.015"]
    (tmp_path / "goal0.02_delay0.2_depth0.015.json").write_text('{"kappa": "x", "nope": 1}')
    code = main(
        ["sim", "--out", str(tmp_path / "o"), "--sweep", *grid, "--cell-configs", str(tmp_path)]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("dsteleop sim: error: --cell-configs ") and "depth0.015.json" in err[0]


# --- scripts/tune_sweep.py: its cells, its commands and its merge --------------------------------


def _tune_sweep() -> Any:
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "scripts" / "tune_sweep.py"
    spec = importlib.util.spec_from_file_location("tune_sweep", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


DOCS_TUNED = Path(__file__).resolve().parent / "golden" / "tune-best"


def test_tune_sweep_tunes_the_cells_the_sweep_runs_with_the_cells_world() -> None:
    ts = _tune_sweep()
    g = sweep.default_grid()
    assert ts.cells("axes") == sweep.design_cells(g, "axes", sweep.centre(planar.SimConfig()))
    assert ts.cells("grid") == g.cells() and len(ts.cells("axes")) == 7
    budget = ["--trials-per-param", "4", "--widen-edges", "2"]
    cmd = ts.tune_command((0.04, 0.2, 0.0), "scalar", Path("o/x"), budget, 200, 2)
    assert cmd[:2] == ["dsteleop", "tune"]
    opt = dict(zip(cmd[2::2], cmd[3::2], strict=False))
    assert opt["--mode"] == "scalar" and opt["--metric"] == "success"
    assert (opt["--goal-sigma"], opt["--delay"], opt["--depth-sigma"]) == ("0.04", "0.2", "0")
    assert (opt["--trials-per-param"], opt["--widen-edges"]) == ("4", "2")
    assert (opt["--trajectories"], opt["--study-seed"]) == ("200", "0")
    # The same budget for every mode: the commands differ only in the mode and the folder.
    ds = ts.tune_command((0.04, 0.2, 0.0), "DS", Path("o/y"), budget, 200, 2)
    assert [a for a, b in zip(cmd, ds, strict=True) if a != b] == ["scalar", "o/x"]


def test_tune_sweep_merges_the_modes_best_files_as_both_json() -> None:
    ts = _tune_sweep()
    bests = {m: json.loads((DOCS_TUNED / f"{m}.json").read_text()) for m in ("DS", "scalar")}
    both = json.loads((DOCS_TUNED / "both.json").read_text())["arbitration"]
    merged = ts.merge_best(bests)
    assert merged == both and list(merged) == list(both)
    # The cell's file is a --config file that gives that arbitration.
    from dsteleop.app.cli.options import config_from_file

    data = ts.cell_file((0.02, 0.2, 0.015), bests)
    assert set(data["objective"]) == {"DS", "scalar"}
    assert "goal0.02_delay0.2_depth0.015" in data["note"]

    def read(d: dict[str, Any], name: str) -> Any:
        path = Path(os.environ.get("TMPDIR", "/tmp")) / f"tune_sweep_{os.getpid()}_{name}.json"
        path.write_text(json.dumps(d))
        try:
            return config_from_file(path, [])
        finally:
            path.unlink()

    assert read(data, "cell").to_dict() == read({"arbitration": both}, "both").to_dict()
    # Conflicts are refused: one parameter tuned two ways, or modes from different bases.
    clash = json.loads(json.dumps(bests))
    clash["scalar"]["objective"]["params"]["kappa"] = 1.0
    with pytest.raises(InputError, match="kappa tuned by DS and scalar"):
        ts.merge_best(clash)
    other = json.loads(json.dumps(bests))
    other["scalar"]["arbitration"]["v_max_mps"] = 0.3
    with pytest.raises(InputError, match=r"scalar was tuned from another base \(v_max_mps\)"):
        ts.merge_best(other)
    with pytest.raises(FormatError, match=r"not a tune best\.json"):
        ts.merge_best({"DS": both})


def test_tune_sweep_dry_run_prints_every_command_and_writes_nothing(tmp_path: Path) -> None:
    script = Path(__file__).resolve().parents[1] / "scripts" / "tune_sweep.py"
    out = tmp_path / "cells"
    proc = subprocess.run(
        [sys.executable, str(script), "--out", str(out), "--dry-run", "--trials", "3"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 7 * 2 and all(x.startswith("dsteleop tune ") for x in lines)
    assert not out.exists()


def test_tune_sweep_reuses_a_mode_tuned_elsewhere_and_refuses_a_missing_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--reuse DS=DIR`: DS as tuned in DIR merged with the modes tuned here (the scalar given
    DS's trial count); its runs are read, not rerun; a missing run is one line, exit 2."""
    ts = _tune_sweep()
    bests = {m: json.loads((DOCS_TUNED / f"{m}.json").read_text()) for m in ("DS", "scalar")}
    elsewhere, out = tmp_path / "cells", tmp_path / "equal"
    for cell in ts.cells("axes"):
        for root, mode in ((elsewhere, "DS"), (out, "scalar")):
            run = root / "runs" / sweep.cell_name(cell) / mode
            run.mkdir(parents=True)
            (run / "best.json").write_text(json.dumps(bests[mode]))
    args = ["--out", str(out), "--modes", "scalar", "--trials", "28"]
    assert ts.main([*args, "--reuse", f"DS={elsewhere}"]) == 0
    data = json.loads((out / "goal0.02_delay0.2_depth0.015.json").read_text())
    assert data["arbitration"] == ts.merge_best(bests)
    assert set(data["objective"]) == {"scalar", "DS"}
    assert f"--reuse DS={elsewhere}" in (out / "README.md").read_text()
    # A run's best.json that is not one: one line naming the cell, exit 2, no traceback.
    broken = elsewhere / "runs" / "goal0_delay0.2_depth0.015" / "DS" / "best.json"
    broken.write_text(json.dumps({"arbitration": bests["DS"]["arbitration"]}))
    capsys.readouterr()
    assert ts.main([*args, "--reuse", f"DS={elsewhere}"]) == 2
    err = capsys.readouterr().err
    assert (
        err == "tune_sweep: goal0_delay0.2_depth0.015: DS: not a tune best.json (no "
        "arbitration or objective.params)\n"
    )
    broken.unlink()
    with pytest.raises(SystemExit) as exc:
        ts.main([*args, "--reuse", f"DS={elsewhere}"])
    assert exc.value.code == 2


# --- a real sweep with a configuration per cell, on a local Ray cluster of 2 workers -------------


@pytest.mark.slow
def test_axes_sweep_runs_each_cell_with_its_own_configuration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Three cells of the axes design over a 2 x 2 grid (the fourth is not run, and needs no
    file); in one cell the scalar baseline is at its defaults (so it is S, trial for trial),
    in another at both.json's tuned cap and scale (so it is not)."""
    configs = tmp_path / "configs"
    configs.mkdir()
    both = json.loads((DOCS_TUNED / "both.json").read_text())
    files = {
        "goal0.02_delay0.2_depth0.015": both,
        "goal0_delay0.2_depth0.015": {"arbitration": {"kappa": 5.0}},
        "goal0.02_delay0_depth0.015": {},
    }
    for name, data in files.items():
        (configs / f"{name}.json").write_text(json.dumps(data))
    out = tmp_path / "sweep"
    grid = ("goal=0,0.02", "delay=0,0.2", "depth=0.015")
    args = [
        "sim", "--no-progress", "--out", str(out), "--trajectories", "6", "--seed", "4",
        "--modes", "S,DS,scalar", "--workers", "2", "--sweep", *grid,
        "--sweep-design", "axes", "--cell-configs", str(configs),
    ]  # fmt: skip

    def run(*extra: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "dsteleop.app.cli.main", *args, *extra],
            capture_output=True, text=True, timeout=900, check=False,
        )  # fmt: skip

    first = run()
    assert first.returncode == 0, first.stderr
    printed = json.loads(first.stdout)
    assert (printed["cells"], printed["computed"], printed["failed"]) == (3, 3, 0)
    raw = {p.stem: json.loads(p.read_text()) for p in sorted((out / "cells").glob("*.json"))}
    assert set(raw) == set(files)
    s = json.loads((out / "sweep.json").read_text())
    assert s["design"] == "axes" and "arbitration" not in s["config"]
    assert s["centre"] == {"goal_sigma_m": 0.02, "delay_s": 0.2, "depth_sigma_m": 0.015}
    import hashlib

    from dsteleop.arbitration import ArbitrationConfig

    md = (out / "sweep.md").read_text()
    assert "Design: axes" in md and "| verdict | configuration |" in md
    for name, data in files.items():
        path = configs / f"{name}.json"
        record = {"file": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
        assert raw[name]["configuration"] == record and s["cell_configs"][name] == record
        summary = next(c for c in s["cells"] if c["name"] == name)
        assert summary["configuration"] == record
        assert f"`{name}.json` {record['sha256'][:12]} |" in md
        want = ArbitrationConfig.from_dict(data.get("arbitration", {})).to_dict()
        assert raw[name]["settings"]["arbitration"] == want
    # At its defaults the scalar baseline is S, trial for trial; tuned, it is not.
    plain = raw["goal0.02_delay0_depth0.015"]["modes"]
    assert plain["scalar"]["success"] == plain["S"]["success"]
    np.testing.assert_allclose(plain["scalar"]["time_s"], plain["S"]["time_s"], atol=1e-9)
    tuned = raw["goal0.02_delay0.2_depth0.015"]["modes"]
    assert not np.allclose(tuned["scalar"]["time_s"], tuned["S"]["time_s"])
    # A cell run alone with its file's arbitration gives the sweep's results.
    cfg = planar.SimConfig(
        trajectories=6, seed=4, modes=(Mode.S, Mode.DS, Mode.SCALAR),
        arbitration=ArbitrationConfig.from_dict(both["arbitration"]),
    )  # fmt: skip
    alone = sweep.cell_task(cfg, (0.02, 0.2, 0.015))
    for mode in ("S", "DS", "scalar"):
        assert alone["modes"][mode]["success"] == tuned[mode]["success"]
        np.testing.assert_allclose(alone["modes"][mode]["time_s"], tuned[mode]["time_s"], atol=1e-9)

    # Resume with the same files computes nothing; the grid design reuses the three cells
    # but needs the fourth cell's file.
    again = run("--resume")
    assert again.returncode == 0, again.stderr
    assert (json.loads(again.stdout)["computed"], json.loads(again.stdout)["resumed"]) == (0, 3)

    def refused(*extra: str) -> str:
        code = main([*args, "--resume", *extra])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1
        return err[0]

    assert "no goal0_delay0_depth0.015.json (1 of 4 cells" in refused("--sweep-design", "grid")
    # A cell whose file now gives other parameters, or is another file with the same ones,
    # or one configuration for every cell: refused, per cell.
    name = "goal0_delay0.2_depth0.015"
    (configs / f"{name}.json").write_text(json.dumps({"arbitration": {"kappa": 6.0}}))
    assert f"{name}.json was computed with other settings" in refused()
    (configs / f"{name}.json").write_text(json.dumps({"kappa": 5.0}))
    assert f"{name}.json was computed with another configuration" in refused()
    plain_args = [a for a in args if a not in ("--cell-configs", str(configs))]
    code = main([*plain_args, "--resume"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "was computed with other settings" in err[0]


def test_tune_sweep_stops_in_one_line_on_a_corrupt_best_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A best.json that a crashed or interrupted tune left half-written is one line and exit
    2 (scripts/tune_sweep.py reads each run's best.json through app/jsonable.read_json), not a
    JSONDecodeError traceback."""
    ts = _tune_sweep()
    cell = ts.cells("axes")[0]
    best = tmp_path / "runs" / ts.cell_name(cell) / "DS" / "best.json"
    best.parent.mkdir(parents=True)
    best.write_text('{"arbitration": {"kappa": 8')  # cut mid-file
    assert ts.main(["--out", str(tmp_path), "--modes", "DS", "--trials", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"tune_sweep: {ts.cell_name(cell)}: {best}: not a JSON file"), err
