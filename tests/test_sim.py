"""`dsteleop sim`: success test, determinism, paired runs, what the study shows, bad arguments."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.cli.main import main
from dsteleop.app.operator.world import Impairments
from dsteleop.app.session.trace import Trace
from dsteleop.app.study import batch, planar, results
from dsteleop.app.study import summary as study_summary
from dsteleop.arbitration import ArbitrationInput, HandState, Mode, make_arbiter


def run_cli(*args: str) -> int:
    return main(["sim", "--no-progress", *args])


# --- the success test and the planar embedding ----------------------------------------------


def test_success_region_radius_and_heading() -> None:
    handle, normal, R, delta = (0.3, 0.4), math.pi / 4, 0.03, 0.35
    xy = np.array([[0.3, 0.4], [0.3 + 0.029, 0.4], [0.3 + 0.031, 0.4], [0.3, 0.4], [0.3, 0.4]])
    heading = np.array([normal, normal, normal, normal + 0.34, normal - 0.36])
    got = planar.in_success_region(xy, heading, handle, normal, R, delta)
    assert got.tolist() == [True, True, False, True, False]


def test_success_heading_wraps_around() -> None:
    # A heading a full turn away is the same heading; pi away is not.
    heading = np.array([0.1 + 2 * np.pi, -0.1 - 2 * np.pi, 0.1 + np.pi])
    ok = planar.in_success_region(np.zeros((3, 2)), heading, (0.0, 0.0), 0.0, 0.01, 0.2)
    assert ok.tolist() == [True, True, False]
    np.testing.assert_allclose(
        planar.wrap(np.array([3 * np.pi / 2, -3 * np.pi / 2])), [-np.pi / 2, np.pi / 2]
    )


def test_planar_state_round_trip() -> None:
    h = np.array([-3.0, -1.0, 0.0, 0.7, 3.1])
    X = planar.planar_state(np.arange(5.0), np.ones(5), h)
    assert (
        X.position.shape == (5, 3) and X.rotation.shape == (5, 3, 3) and X.openness.shape == (5, 0)
    )
    np.testing.assert_allclose(planar.heading_of(X.rotation), h, atol=1e-12)
    assert np.all(X.position[:, 2] == 0.0)


def test_success_and_time_of_open_loop_trials() -> None:
    # Manual mode reproduces the hand exactly (F = 0 fingers, z/roll/pitch fixed): the
    # operator reaches the handle, so manual succeeds; its cosine distance is 0 and its
    # agreement 1. Autonomous ends at the robot's noisy goal.
    cfg = planar.SimConfig(trajectories=12, seed=5, operator="side")
    res = results.merge(cfg, [batch.run_chunk(cfg, range(12))])
    man = res.modes["manual"]
    assert man.success.mean() >= 11 / 12
    np.testing.assert_allclose(man.cosine_mean, 0.0, atol=1e-12)
    np.testing.assert_array_equal(man.agreement, 1.0)
    goals = np.stack([planar.sample_trial(cfg, i).robot_goal for i in range(12)])
    auto = res.modes["autonomous"]
    np.testing.assert_allclose(auto.final[:, :2], goals[:, :2], atol=0.01)
    inside = np.linalg.norm(goals[:, :2] - cfg.handle_xy_m, axis=1) <= cfg.success_radius_m
    # Autonomous succeeds exactly when its goal noise lands within R (heading is exact).
    assert (auto.success == inside).mean() >= 11 / 12
    for r in res.modes.values():
        np.testing.assert_array_equal(r.lengths, res.lengths)  # the operator sets the length
        L = res.lengths * cfg.dt_s
        assert np.all((r.time_s > 0) & (r.time_s <= L))
        assert np.all(
            r.time_s[~r.success] == pytest.approx((res.lengths[~r.success] - 1) * cfg.dt_s)
        )


CLEAR = Impairments.unimpaired()


def test_closed_loop_trials_end_when_the_operator_is_done() -> None:
    """The closed-loop operator decides when a trial ends: it commits (manual: the robot is
    the hand, so it gets there and holds still at its own target within its tolerance, as it
    sees it), or gives up at its patience (autonomous with a goal 6 cm off: the robot cannot
    be moved and is outside even the task's tolerance it settles for). The robot stays in its
    plane."""
    cfg = planar.SimConfig(trajectories=12, seed=5, modes=(Mode.MANUAL,), world=CLEAR, attempts=1)
    res = results.merge(cfg, [batch.run_chunk(cfg, range(12))])
    man = res.modes["manual"]
    assert man.committed.all() and not man.gave_up.any() and man.success.mean() >= 11 / 12
    np.testing.assert_allclose(man.cosine_mean, 0.0, atol=1e-12)
    goals = np.stack([planar.sample_closed_trial(cfg, i).operator_goal for i in range(12)])
    err = np.linalg.norm(man.final[:, :2] - goals[:, :2], axis=1)
    # Within its tolerance as it sees it (it misjudges the robot by a few mm).
    assert np.all(err <= cfg.operator_tolerance_m + 0.012)
    assert np.all(np.abs(planar.wrap(man.final[:, 2] - goals[:, 2])) <= cfg.operator_tolerance_rad)
    patience = cfg.operator_profile.patience_s
    assert np.all(man.time_s < patience)
    np.testing.assert_allclose(man.time_s, (man.lengths - 1) * cfg.dt_s)
    far = dataclasses.replace(
        cfg, modes=(Mode.AUTONOMOUS,), world=CLEAR.replace(goal_sigma_m=0.06), trajectories=6
    )
    res = results.merge(far, [batch.run_chunk(far, range(6))])
    auto = res.modes["autonomous"]
    off = np.array(
        [
            np.linalg.norm(planar.robot_goal(far, i, 0)[:2] - far.handle_xy_m) > 0.045
            for i in range(6)
        ]
    )
    assert off.sum() >= 2
    assert auto.gave_up[off].all() and not auto.success[off].any()
    np.testing.assert_allclose(auto.time_s[off], patience, atol=2 * cfg.dt_s)
    cfg = dataclasses.replace(cfg, modes=(Mode.MANUAL, Mode.AUTONOMOUS))
    # One trajectory alone: z, roll and pitch never move (the task is planar).
    ex = batch.example(cfg, 3, Mode.MANUAL)
    X = ex.trace.step.X_next
    np.testing.assert_allclose(X.position[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(X.rotation[:, 2, 2], 1.0, atol=1e-12)


def test_results_do_not_depend_on_chunking() -> None:
    # Per-row results agree to the last few bits whatever the batch: numpy's SIMD maths may
    # round an element differently depending on its position in an array, so bit-identity
    # across chunkings is not promised (it is for the same chunking: see the next tests).
    cfg = planar.SimConfig(trajectories=10, seed=2, modes=(Mode.S, Mode.DS))
    whole = results.merge(cfg, [batch.run_chunk(cfg, range(10))])
    parts = results.merge(cfg, [batch.run_chunk(cfg, range(6, 10)), batch.run_chunk(cfg, range(6))])
    for m in ("S", "DS"):
        a, b = whole.modes[m], parts.modes[m]
        np.testing.assert_allclose(a.cosine_mean, b.cosine_mean, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.agreement, b.agreement, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.final, b.final, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(a.success, b.success)
        np.testing.assert_allclose(a.time_s, b.time_s, rtol=0, atol=1e-12)


@pytest.mark.parametrize("operator", ["side", "closed-loop"])
def test_trace_of_one_trajectory_is_a_session_trace_matching_the_batch(operator: str) -> None:
    # One trajectory ticked alone (what the per-trajectory figures draw) is the same run as
    # in the batch: L states give L - 1 ticks, each arbitrated, ending at the batch's final
    # pose; its cosine distance and agreement are the batch's. A closed-loop operator is
    # the same person alone and in the batch (its draws come from its own generator).
    cfg = planar.SimConfig(trajectories=4, seed=3, modes=(Mode.S, Mode.DS), operator=operator)  # type: ignore[arg-type]
    res = results.merge(cfg, [batch.run_chunk(cfg, range(4))])
    row = 2 * cfg.runs  # trajectory 2's first run
    for mode in cfg.modes:
        tr = batch.trace(cfg, 2, mode)
        assert isinstance(tr, Trace) and tr.mode is mode
        L = int(res.modes[mode.value].lengths[row])
        assert len(tr) == L - 1 and tr.arbitrated.all()
        assert tr.dims == ("x", "y", "z", "roll", "pitch", "yaw")
        assert tr.step.alpha.shape == (L - 1, 6) and tr.step.X_next.position.shape == (L - 1, 3)
        np.testing.assert_allclose(tr.t_s, np.arange(1, L) * cfg.dt_s)
        final = res.modes[mode.value].final[row]
        np.testing.assert_allclose(tr.p_robot[-1, :2], final[:2], atol=1e-9)
        heading = planar.heading_of(tr.step.X_next.rotation[-1])
        assert float(planar.wrap(np.array(heading - final[2]))) == pytest.approx(0.0, abs=1e-9)
        U_h, U_o = tr.step.U_human, tr.step.U_out
        assert np.all(np.isfinite(U_h)) and np.all(np.isfinite(U_o))
        agree = np.einsum("td,td->t", U_h, U_o) > 0
        # Idle actions (the operator's or the output's norm <= 1e-9) are skipped, as by the
        # cosine distance.
        moving = (np.linalg.norm(U_h, axis=-1) > 1e-9) & (np.linalg.norm(U_o, axis=-1) > 1e-9)
        ratio = agree[moving].sum() / moving.sum()
        assert ratio == pytest.approx(res.modes[mode.value].agreement[row], abs=1e-9)


def test_trials_are_paired_and_seeded() -> None:
    cfg = planar.SimConfig(trajectories=3, seed=9, operator="side")
    a, b = planar.sample_trial(cfg, 1), planar.sample_trial(cfg, 1)
    np.testing.assert_array_equal(a.hand.position, b.hand.position)
    np.testing.assert_array_equal(a.robot_goal, b.robot_goal)
    c = planar.sample_trial(cfg, 2)
    assert not np.array_equal(a.robot_goal, c.robot_goal)
    # The side operator prefers a heading below the normal; the aligned one the normal.
    assert a.operator_goal[2] < cfg.handle_normal_rad - cfg.side_offset_rad[0] + 1e-12
    al = planar.sample_trial(planar.SimConfig(trajectories=3, seed=9, operator="aligned"), 1)
    assert al.operator_goal[2] == cfg.handle_normal_rad


# --- the command ----------------------------------------------------------------------------


def test_same_seed_gives_byte_identical_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def summary(name: str, seed: str, workers: str) -> bytes:
        d = tmp_path / name
        args = ("--trajectories", "120", "--seed", seed, "--out", str(d), "--workers", workers)
        assert run_cli(*args, "--no-figures") == 0
        return (d / "summary.json").read_bytes()

    assert summary("a", "4", "1") == summary("b", "4", "1")
    two = summary("c", "4", "2")
    assert two == summary("d", "4", "2")
    # Across worker counts the numbers agree (to the last bits, see the chunking test).
    _assert_close(json.loads(summary("a", "4", "1")), json.loads(two))
    assert summary("e", "5", "1") != summary("a", "4", "1")
    capsys.readouterr()


def _assert_close(a: object, b: object) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_close(a[k], b[k])
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _assert_close(x, y)
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12)
    else:
        assert a == b


def test_outputs_and_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        run_cli("--trajectories", "12", "--seed", "1", "--out", str(tmp_path), "--example", "3")
        == 0
    )
    printed = json.loads(capsys.readouterr().out)
    assert printed["files"][:2] == ["summary.json", "summary.md"]
    s = json.loads((tmp_path / "summary.json").read_text())
    for mode in ("S", "DS", "manual", "autonomous"):
        m = s["modes"][mode]
        for key in ("success_rate", "cosine_distance", "agreement", "time_s"):
            assert key in m
        assert 0.0 <= m["success_rate"]["estimate"] <= 1.0
        assert 0.0 <= m["gave_up_share"] <= 1.0
        for variant in ("literal", "normalised", "translation", "rotation", "dead_band"):
            assert set(m["metric_variants"][variant]) == {"about", "cosine_distance", "agreement"}
        assert "fingers" in m["metric_variants"] and "by_phase" in m["metric_variants"]
    assert s["seed"] == 1 and s["config"]["seed"] == 1
    assert s["operator"]["kind"] == "closed-loop" and s["operator"]["closed_loop"]
    assert s["config"]["arbitration"]["kappa"] == 4.0
    # Fig. 5/6 and the x-per-y remark come from the open-loop side operator, as in the paper.
    fig = s["fig5_fig6"]
    assert fig["operator"] == "side" and fig["trajectories"] == 12 and "S" in fig and "DS" in fig
    assert printed["fig5_operator"] == "side"
    assert "S_vs_DS" in s["tests"]
    assert 0.0 <= s["tests"]["S_vs_DS"]["agreement"]["two_sample_t"]["p_value"] <= 1.0
    md = (tmp_path / "summary.md").read_text()
    assert "| Mode | Success Rate | Trial Time (s) | Cosine Distance | Ratio of Agreement |" in md
    assert "not that study" in md and "open-loop `side` operator" in md
    for name in ("fig5b_distributions.png", "fig5c_heading.png", "fig5d_xy.png", "fig6_alpha.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


# --- what the study shows (docs/sim.md): the mechanisms, as rates over trajectories -------


def test_s_forces_x_while_the_operator_moves_along_y_only() -> None:
    """The paper's Fig. 5 remark, from the open-loop operator as in the paper: while it moves
    along y only, S's output adds far more x motion than DS's (paired over trajectories)."""
    cfg = planar.SimConfig(trajectories=120, seed=11, modes=(Mode.S, Mode.DS), operator="side")
    res = results.merge(cfg, [batch.run_chunk(cfg, range(120))])
    fig = study_summary.fig5_remark(res)
    assert fig["S"]["n"] >= 60
    assert fig["DS"]["mean"] < 0.7 * fig["S"]["mean"]
    assert fig["paired_t_S_minus_DS"]["t"] > 0 and fig["paired_t_S_minus_DS"]["p_value"] < 1e-6
    # DS keeps alpha_x low while the operator is not moving in x (Fig. 6): over the ticks
    # where the operator moves along y only, mean alpha_x of DS is below S's.
    k = planar.first_lead_index(cfg)
    alphas = {}
    for mode in (Mode.S, Mode.DS):
        tr = batch.trace(cfg, k, mode)
        vx, vy = np.abs(tr.step.U_human[:, 0]), np.abs(tr.step.U_human[:, 1])
        y_only = (vy > results.Y_ONLY_MPS) & (vx < 0.1 * vy)
        alphas[mode.value] = float(tr.step.alpha[y_only, 0].mean())
    assert alphas["DS"] < alphas["S"]


def test_under_ds_the_operator_corrects_the_robots_goal_error() -> None:
    """The goal-noise mechanism alone (no delay, no single view): the closed-loop operator
    watches the robot and steers it to the TRUE handle; the robot aims at a goal 2 cm (sd
    per axis) off. Under S the robot parks at its own goal (alpha -> 1 near it), so the
    operator cannot correct it; under DS the operator moves the robot towards the handle: it
    ends nearer the handle than S on most trajectories whose goal is off, and succeeds more."""
    n = 80
    world = CLEAR.replace(goal_sigma_m=0.02)
    cfg = planar.SimConfig(
        trajectories=n, seed=21, modes=(Mode.S, Mode.DS), world=world, attempts=1
    )
    res = results.merge(cfg, [batch.run_chunk(cfg, range(n))])
    S, DS = res.modes["S"], res.modes["DS"]
    goals = np.stack([planar.robot_goal(cfg, i, 0) for i in range(n)])
    handle = np.asarray(cfg.handle_xy_m)
    d_S = np.linalg.norm(S.final[:, :2] - handle, axis=1)
    d_DS = np.linalg.norm(DS.final[:, :2] - handle, axis=1)
    # S: parked at its noisy goal.
    np.testing.assert_allclose(S.final[:, :2], goals[:, :2], atol=2e-3)
    # DS: corrected towards the handle where the goal was off.
    off = np.linalg.norm(goals[:, :2] - handle, axis=1) > cfg.success_radius_m
    assert off.sum() >= 15
    assert np.mean(d_DS[off] < d_S[off]) >= 0.8
    # (It corrects until the robot is within the task's radius as it sees it: having felt
    # the robot resist, it settles for the task's tolerance.)
    assert np.median(d_DS[off]) < np.median(d_S[off])
    assert DS.success.mean() >= S.success.mean() + 0.1


# --- the operator's world (docs/operator.md): no built-in impossibility, settled outcomes,
# the delay on both paths, runs with a history -----------------------------------------------


def test_every_mode_satisfies_the_operator_without_noise_or_delay() -> None:
    """No built-in impossibility: in a world without goal noise, delay or single-view depth
    error, the operator commits (and succeeds) in every mode, S and autonomous included (it
    settles for the task's tolerance where the robot resists its own heading)."""
    n = 100
    cfg = planar.SimConfig(trajectories=n, seed=3, world=CLEAR, attempts=1)
    res = results.merge(cfg, [batch.run_chunk(cfg, range(n))])
    for name, r in res.modes.items():
        assert r.committed.mean() >= 0.95, name
        assert r.success.mean() >= 0.95, name
        assert not r.success[~r.committed].any()


def test_success_is_judged_on_the_committed_settled_pose() -> None:
    """Success is the robot's pose after the grasp settled, not a snapshot when the operator
    commits: the same people (paired rows) judged at the commit (no grasp time) and after a
    3 s grasp, under DS with a goal 4 cm off (the robot, left alone once the hand stops,
    drifts towards its noisy goal): some snapshot successes fail when judged settled; a
    trial that ends by giving up never succeeds."""
    world = CLEAR.replace(goal_sigma_m=0.04)
    base = planar.SimConfig(trajectories=60, seed=4, modes=(Mode.DS,), world=world, attempts=1)
    snap = dataclasses.replace(base, grasp_s=0.0)
    settled = dataclasses.replace(base, grasp_s=3.0)
    a = results.merge(snap, [batch.run_chunk(snap, range(60))]).modes["DS"]
    b = results.merge(settled, [batch.run_chunk(settled, range(60))]).modes["DS"]
    np.testing.assert_array_equal(a.committed, b.committed)  # the same people, the same commits
    np.testing.assert_allclose(b.time_s[b.committed] - a.time_s[a.committed], 3.0, atol=0.05)
    assert np.sum(a.success & ~b.success) >= 3
    assert not a.success[a.gave_up].any() and not b.success[b.gave_up].any()


def test_the_delay_reaches_both_paths() -> None:
    """The same person (same seed) in manual mode: with a link delay the robot's first
    motion comes 2 delay_s later (the person sees the robot delay_s late, and its command
    reaches the robot delay_s late)."""

    def first_motion(delay: float) -> float:
        cfg = planar.SimConfig(
            trajectories=1, seed=6, modes=(Mode.MANUAL,), world=CLEAR.replace(delay_s=delay)
        )
        tr = batch.trace(cfg, 0, Mode.MANUAL)
        moving = np.linalg.norm(tr.step.U_out, axis=-1) > 1e-9
        return float(tr.t_s[np.argmax(moving)])

    assert first_motion(0.3) - first_motion(0.0) == pytest.approx(0.6, abs=0.04)


def test_runs_feed_the_history_term_from_the_second_run() -> None:
    """Each person makes `attempts` runs in each mode; eq (6)'s history term of a run is the
    mean direction of its previous runs: zero in the first, non-zero from the second."""
    cfg = planar.SimConfig(trajectories=8, seed=2, modes=(Mode.S, Mode.DS), attempts=3)
    res = results.merge(cfg, [batch.run_chunk(cfg, range(8))])
    for r in res.modes.values():
        assert r.success.size == 24
        np.testing.assert_array_equal(r.attempt, np.tile([0, 1, 2], 8))
        assert np.all(r.history_norm[r.attempt == 0] == 0.0)
        assert np.all(r.history_norm[r.attempt > 0] > 0.5)
    s = study_summary.summarise(res)
    assert s["runs"] == 3 and len(s["modes"]["DS"]["runs"]) == 3
    assert s["modes"]["DS"]["runs"][0]["history_term_l1"] == 0.0


def test_a_history_term_per_row_is_each_rows_own() -> None:
    """The arbitration takes one history term per row of a batch (each row its operator):
    a batch of two rows with different terms steps as each row alone with its own."""
    rng = np.random.default_rng(0)

    def state() -> HandState:
        return planar.planar_state(
            rng.uniform(0, 0.3, 2), rng.uniform(0, 0.4, 2), rng.uniform(0, 1, 2)
        )

    H, Hp, Hs, X, Xp, Xs, G = (state() for _ in range(7))
    h = np.array([[0.5, -0.5, 0, 0, 0, 1.0], [-0.7, 0.7, 0, 0, 0, -1.0]])
    arb = make_arbiter(Mode.DS)

    def step(rows: list[int], hist: NDArray[np.float64]) -> NDArray[np.float64]:
        sel = np.array(rows)
        inp = ArbitrationInput(
            X_human=H.take(sel), X_human_prev=Hp.take(sel), X_human_start=Hs.take(sel),
            X_current=X.take(sel), X_prev=Xp.take(sel), X_start=Xs.take(sel),
            X_goal=G.take(sel), dt=1 / 30, history_term=hist,
        )  # fmt: skip
        return arb.step(arb.initial_state(6, batch=(len(rows),)), inp)[1].psi_human

    both = step([0, 1], h)
    np.testing.assert_allclose(both[0], step([0], h[0])[0], atol=1e-12)
    np.testing.assert_allclose(both[1], step([1], h[1])[0], atol=1e-12)
    assert not np.allclose(both[0], step([0], h[1])[0])


# --- bad arguments --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--trajectories", "-5"], "trajectories must be >= 1"),
        (["--trajectories", "0"], "trajectories must be >= 1"),
        (["--workers", "-1"], "--workers must be >= 0"),
        (["--modes", "S,XYZ"], "unknown mode 'XYZ'"),
        (["--operator", "robot"], "unknown operator 'robot'"),
        (["--example", "50"], "example must be in [0, 9]"),
        (["--param", "kappa=-1"], "kappa must be finite and > 0"),
        (["--param", "nonsense=1"], "unknown arbitration parameter"),
        (["--goal-sigma", "-0.1"], "goal_sigma_m must be a number >= 0"),
        (["--delay", "-1"], "delay_s must be a number >= 0"),
        (["--depth-sigma", "nan"], "depth_sigma_m must be a number >= 0"),
        (["--attempts", "0"], "attempts must be >= 1"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    code = run_cli("--trajectories", "10", "--out", str(tmp_path / "o"), *args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("dsteleop sim: error:") and message in err[0]


def test_unwritable_out_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    code = run_cli("--trajectories", "5", "--out", str(blocker / "sub"))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--out: cannot write to" in err[0]


def test_cli_subprocess_bad_argument_no_traceback(tmp_path: Path) -> None:
    def sim(trajectories: str) -> subprocess.CompletedProcess[str]:
        args = ["sim", "--trajectories", trajectories, "--out", str(tmp_path)]
        return subprocess.run(
            [sys.executable, "-m", "dsteleop.app.cli.main", *args],
            capture_output=True,
            check=False,
            text=True,
            timeout=60,
        )

    proc = sim("-1")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert (
        proc.stderr.strip().splitlines()[-1]
        == "dsteleop sim: error: --trajectories must be >= 1, got -1"
    )
    # argparse's own errors (not an integer) are one line and exit 2 too.
    proc = sim("many")
    assert proc.returncode == 2 and "invalid int value" in proc.stderr


def test_summary_reports_the_papers_metrics_and_labels_the_others() -> None:
    """Cosine distance as the paper's sum (geometric mean over trajectories), the per-action
    mean beside it; idle actions skipped alike; censored times counted; Fig. 8's pairs, each
    mode's hand against its own robot; McNemar for paired success."""
    from dsteleop.arbitration import metrics

    cfg = planar.SimConfig(trajectories=10, seed=2, modes=(Mode.S, Mode.DS, Mode.MANUAL))
    res = results.merge(cfg, [batch.run_chunk(cfg, range(10))])
    s = study_summary.summarise(res)
    for name, r in res.modes.items():
        m = s["modes"][name]
        cos = m["cosine_distance"]
        assert cos["arithmetic_mean"] == pytest.approx(float(r.cosine_sum.mean()))
        assert cos["per_action_mean"]["mean"] == pytest.approx(float(np.nanmean(r.cosine_mean)))
        assert "LABELLED" in cos["per_action_mean"]["label"]
        if name != "manual":
            gm = float(np.exp(np.mean(np.log(r.cosine_sum))))
            assert cos["geometric_mean"] == pytest.approx(gm)
            # A sum over many actions, not a mean in [0, 2].
            assert cos["geometric_mean"] > 2.0
        assert cos["skipped_idle"] == int(r.n_idle.sum()) == m["agreement"]["skipped_idle"]
        t = m["time_s"]
        assert t["geometric_mean"] == pytest.approx(float(np.exp(np.mean(np.log(r.time_s)))))
        assert t["arithmetic_mean"] == pytest.approx(float(r.time_s.mean()))
        assert t["censored"]["gave_up"] == int(r.gave_up.sum())
        assert t["censored"]["count"] >= t["censored"]["gave_up"]
    # S parks its robot at its goal: outputs exactly zero there are idle, not disagreements.
    assert s["modes"]["S"]["cosine_distance"]["skipped_idle"] > 0
    div = s["divergence"]["fig8"]
    S, DS = res.modes["S"], res.modes["DS"]
    assert div["operator_S~robot_S"] == pytest.approx(metrics.js_divergence(S.hand_hist, S.hist))
    assert div["operator_DS~operator_S"] == pytest.approx(
        metrics.js_divergence(DS.hand_hist, S.hand_hist)
    )
    assert div["robot_DS~robot_S"] == pytest.approx(metrics.js_divergence(DS.hist, S.hist))
    assert s["divergence"]["operator_vs_robot"]["manual"] == pytest.approx(0.0, abs=1e-12)
    mc = s["tests"]["S_vs_DS"]["success_mcnemar"]
    assert mc["first_only"] == int(np.sum(S.success & ~DS.success))
    assert mc["second_only"] == int(np.sum(~S.success & DS.success))


def test_tape_scatters_each_block_of_ticks_to_its_rows() -> None:
    # The rows shrink as trials end (every _CHECK_TICKS ticks); each block of buffered ticks
    # must land on the rows it was of, and the ticks that belong to a trial follow from the
    # trials' lengths.
    B = batch._CHECK_TICKS
    T, J = 3 * B + 4, 7
    epochs = [np.arange(J), np.array([0, 2, 3, 6]), np.array([2, 6])]
    rng = np.random.default_rng(3)
    want_robot, want_hand = np.full((T, J, 3), np.nan), np.full((T, J, 3), np.nan)
    want_uh, want_uo = np.full((T - 1, J, 6), np.nan), np.full((T - 1, J, 6), np.nan)
    tape = batch._Tape(T, J).start(T, J)
    for k in range(T - 1):
        if k % B == 0 and k > 0:
            tape.flush(epochs[k // B - 1])
        rows = epochs[min(k // B, len(epochs) - 1)]
        n = rows.size
        X = planar.planar_state(*rng.uniform(-3.0, 3.0, (3, n)))
        H = planar.planar_state(*rng.uniform(-3.0, 3.0, (3, n)))
        U_h, U_o = rng.standard_normal((n, 6)), rng.standard_normal((n, 6))
        tape.put(k, X, H, U_h, U_o)
        for want, S in ((want_robot, X), (want_hand, H)):
            want[k + 1, rows, :2] = S.position[:, :2]
            want[k + 1, rows, 2] = planar.heading_of(S.rotation)
        want_uh[k, rows], want_uo[k, rows] = U_h, U_o
    tape.flush(epochs[-1])
    for got, want in (
        (tape.robot, want_robot), (tape.hand, want_hand), (tape.U_human, want_uh),
        (tape.U_out, want_uo),
    ):  # fmt: skip
        written = ~np.isnan(want)
        assert np.array_equal(got[written], want[written])
    lengths = np.array([5, T, 30, 12, 1, 9, T])
    tape.close(lengths)
    assert np.array_equal(tape.acted, np.arange(1, T)[:, None] < lengths[None, :])


def test_study_processes_keep_the_memory_they_free() -> None:
    import platform

    from dsteleop.app.study.run import keep_freed_memory

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("mallopt is glibc's")
    assert keep_freed_memory() is True


def test_study_processes_fault_their_memory_in_small_pages() -> None:
    import importlib

    from dsteleop.app.study.run import small_pages

    core: Any = importlib.import_module("numpy._core.multiarray")  # the switch has no stubs
    before = core._get_madvise_hugepage()
    try:
        assert small_pages() is True
        assert core._get_madvise_hugepage() is False
    finally:
        core._set_madvise_hugepage(before)
