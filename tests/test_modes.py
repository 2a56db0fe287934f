"""Modes as plug-ins: a mode defined and registered here, in a test file, reaches the kernel's
mixed batches, the study, tune's spaces, replay's and the viewer's mode lists without an edit
to them; the scalar baseline is S at cap 1 and scale 1; a bad mode or mode parameter is one
line and exit code 2."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.study.core import SimConfig, all_modes, run_chunk
from dsteleop.app.tune.space import default_space, field_kinds, parse_space
from dsteleop.app.tune.trial import StudyBatch, study_task
from dsteleop.app.viewer.server import mode_names
from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    HandState,
    Mode,
    ModeSpec,
    Quantities,
    RowModes,
    make_arbiter,
    register,
    registered,
    so3_exp,
    unregister,
)
from dsteleop.arbitration.modes import check_range
from dsteleop.errors import ConfigError

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]


# --- a mode of this file: half of P(R) per dimension, with one parameter --------------------


@dataclass(frozen=True)
class ShareParams:
    share: float = 0.5

    def __post_init__(self) -> None:
        check_range("share", "share", self.share, 0.0, 1.0)


def share_alpha(params: ShareParams, q: Quantities, rows: NDArray[np.intp], state: None) -> None:
    q.alpha[rows] = params.share * q.P_robot[rows]


SHARE = ModeSpec(
    "share",
    "SHARE",
    share_alpha,
    "share * P(R) per dimension (a test's mode)",
    params=ShareParams,
    space=("share.share=0.1:1",),
)


@pytest.fixture
def share() -> Iterator[Mode]:
    mode = register(SHARE)
    try:
        yield mode
    finally:
        unregister(mode)


def _states(rng: np.random.Generator, M: int, F: int) -> HandState:
    return HandState(
        rng.uniform(-0.5, 0.5, (M, 3)),
        so3_exp(rng.normal(0.0, 1.0, (M, 3))),
        rng.uniform(0.0, 1.0, (M, F)),
    )


def _input(rng: np.random.Generator, M: int, F: int = 4) -> ArbitrationInput:
    S = [_states(rng, M, F) for _ in range(7)]
    return ArbitrationInput(
        X_human=S[0], X_human_prev=S[1], X_human_start=S[2], X_current=S[3], X_prev=S[4],
        X_start=S[5], X_goal=S[6], dt=1.0 / 30.0,
    )  # fmt: skip


def test_a_mode_from_a_test_file_is_everywhere(share: Mode) -> None:
    assert Mode.parse("SHARE") is share is Mode.SHARE
    assert share in list(Mode) and share in registered() and share.value == "share"
    assert "share" in mode_names()  # the viewer's dropdown
    assert share in all_modes() and share in SimConfig().modes  # the study's default modes
    assert default_space("share") == ("share.share=0.1:1",)  # tune's default space
    assert [d.name for d in parse_space([], "share")] == ["share.share"]
    assert field_kinds()["share.share"] is False
    cfg = ArbitrationConfig()
    assert cfg.to_dict()["share.share"] == 0.5 and cfg.params_of("share") == ShareParams()
    assert ArbitrationConfig.from_dict({"share.share": 0.25}).params_of("share").share == 0.25
    with pytest.raises(ConfigError, match=r"share\.share must be in \(0, 1\]"):
        cfg.replace(**{"share.share": 1.5})


def test_a_mixed_batch_with_a_new_mode_equals_each_mode_alone(share: Mode) -> None:
    """Rows of share, DS, S and scalar in one batch: each row is what its mode gives alone."""
    rng = np.random.default_rng(3)
    M = 12
    modes = [share, Mode.DS, Mode.S, Mode.SCALAR] * 3
    cfg = ArbitrationConfig(window=3).replace(**{"share.share": 0.8, "scalar.cap": 0.7})
    mixed_arb = make_arbiter(Mode.DS, cfg)
    singles = {m: make_arbiter(m, cfg) for m in set(modes)}
    fs_mixed = mixed_arb.initial_state(10, (M,))
    fs_single = {m: a.initial_state(10, (M,)) for m, a in singles.items()}
    rows = RowModes.of(modes)
    for _ in range(4):  # through DS's windows
        inp = _input(rng, M)
        fs_mixed, mixed = mixed_arb.step(fs_mixed, inp, rows)
        for m, arb in singles.items():
            fs_single[m], alone = arb.step(fs_single[m], inp)
            idx = [k for k, mk in enumerate(modes) if mk is m]
            for name in STEP_ARRAYS:
                np.testing.assert_array_equal(getattr(mixed, name)[idx], getattr(alone, name)[idx])
            np.testing.assert_array_equal(mixed.X_next.position[idx], alone.X_next.position[idx])
    share_rows = [k for k, m in enumerate(modes) if m is share]
    np.testing.assert_allclose(mixed.alpha[share_rows], 0.8 * mixed.P_robot[share_rows])


def test_only_the_quantities_a_mode_reads_changes_no_action(share: Mode) -> None:
    """every_quantity=False (the study's ticks): alpha, the actions, U_out and X_next are
    those of a full tick; eq (4)-(7) are computed for the rows of modes that read them (DS,
    and a plug-in that does not say otherwise) and NaN in the others."""
    rng = np.random.default_rng(5)
    modes = [share, Mode.DS, Mode.S, Mode.SCALAR, Mode.MANUAL, Mode.AUTONOMOUS] * 2
    M = len(modes)
    arb = make_arbiter(Mode.DS, ArbitrationConfig(window=3))
    rows = RowModes.of(modes)
    fs_full, fs_part = arb.initial_state(10, (M,)), arb.initial_state(10, (M,))
    reads = np.array([m in (share, Mode.DS) for m in modes])
    for _ in range(4):  # through DS's windows
        inp = _input(rng, M)
        fs_full, full = arb.step(fs_full, inp, rows)
        fs_part, part = arb.step(fs_part, inp, rows, every_quantity=False)
        for name in ("alpha", "U_human", "U_robot", "U_out"):
            np.testing.assert_array_equal(getattr(part, name), getattr(full, name))
        np.testing.assert_array_equal(part.X_next.rotation, full.X_next.rotation)
        for name in ("P_human", "P_robot", "B", "psi_human", "psi_robot"):
            np.testing.assert_array_equal(getattr(part, name)[reads], getattr(full, name)[reads])
            assert np.isnan(getattr(part, name)[~reads]).all()
    # A single-mode batch: S reads none of them, DS all.
    for mode, computed in ((Mode.S, False), (Mode.DS, True)):
        single = make_arbiter(mode)
        _, step = single.step(single.initial_state(10, (2,)), _input(rng, 2), every_quantity=False)
        assert bool(np.isfinite(step.P_robot).all()) is computed
        assert np.isfinite(step.U_out).all()


def test_the_study_and_tune_run_a_new_mode(share: Mode) -> None:
    cfg = SimConfig(trajectories=3, modes=(Mode.S, share), max_paths=0)
    chunk = run_chunk(cfg, [0, 1, 2])
    res = chunk.modes["share"]
    assert res.success.shape == (3 * cfg.attempts,) and np.all(res.time_s > 0)
    m = study_task(StudyBatch(2, 0, "share"), ArbitrationConfig().to_dict())
    runs = 2 * cfg.attempts  # each simulated person makes `attempts` runs
    assert m["study.share.n"] == runs and 0.0 <= m["study.share.agreement"] <= 1.0
    assert m["study.S.n"] == runs


def test_scalar_at_cap_one_scale_one_is_s_to_the_last_bit() -> None:
    rng = np.random.default_rng(11)
    for M, F in ((1, 0), (500, 5)):
        inp = _input(rng, M, F)
        D = 6 + F
        s_arb = make_arbiter(Mode.S)
        c_arb = make_arbiter("scalar")
        _, a = s_arb.step(s_arb.initial_state(D, (M,)), inp)
        _, b = c_arb.step(c_arb.initial_state(D, (M,)), inp)
        for name in STEP_ARRAYS:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        # Its own parameters: the cap scales alpha, a larger scale lowers it.
        capped = make_arbiter("scalar", ArbitrationConfig().replace(**{"scalar.cap": 0.4}))
        _, c = capped.step(capped.initial_state(D, (M,)), inp)
        np.testing.assert_allclose(c.alpha, 0.4 * a.alpha, rtol=1e-15, atol=0)
        steep = make_arbiter("scalar", ArbitrationConfig().replace(**{"scalar.scale": 3.0}))
        _, d = steep.step(steep.initial_state(D, (M,)), inp)
        assert np.all(d.alpha <= a.alpha) and np.any(d.alpha < a.alpha)
        assert np.ptp(d.alpha, axis=-1).max() == 0.0  # one alpha for every dimension


@pytest.mark.parametrize(
    ("name", "value", "match"),
    [
        ("scalar.cap", 0.0, r"scalar\.cap must be in \(0, 1\]"),
        ("scalar.cap", 1.5, r"scalar\.cap must be in \(0, 1\]"),
        ("scalar.cap", float("nan"), r"scalar\.cap"),
        ("scalar.scale", -1.0, r"scalar\.scale must be in \(0, 100\]"),
        ("scalar.nosuch", 1.0, r"unknown parameter scalar\.nosuch"),
        ("nosuch.cap", 1.0, r"unknown mode 'nosuch'"),
        ("S.cap", 1.0, r"mode S has no parameters"),
    ],
)
def test_a_bad_mode_parameter_is_a_config_error(name: str, value: float, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        ArbitrationConfig().replace(**{name: value})


def test_mode_params_round_trip_and_are_recorded() -> None:
    cfg = ArbitrationConfig(kappa=3.0).replace(**{"scalar.cap": 0.6, "scalar.scale": 2.0})
    d = cfg.to_dict()
    assert d["scalar.cap"] == 0.6 and d["scalar.scale"] == 2.0 and d["kappa"] == 3.0
    assert ArbitrationConfig.from_json(cfg.to_json()) == cfg
    assert ArbitrationConfig.from_dict({"kappa": 3.0}).params_of("scalar").cap == 1.0  # old


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, *args], capture_output=True, text=True, timeout=120, cwd=cwd, check=False
    )


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("sim", "--trajectories", "2", "--modes", "S,nosuch", "--out", "o"), "unknown mode"),
        (("sim", "--trajectories", "2", "--param", "scalar.cap=2", "--out", "o"), "scalar.cap"),
        (("replay", "x", "--modes", "nosuch", "--out", "o"), "unknown mode 'nosuch'"),
        (("run", "--mode", "nosuch"), "unknown mode 'nosuch'"),
        (("tune", "--mode", "nosuch", "--trials", "1", "--out", "o"), "unknown mode 'nosuch'"),
        (("tune", "--mode", "manual", "--trials", "1", "--out", "o"), "no parameters of its own"),
        (("tune", "--mode", "S", "--trials", "1", "--out", "o"), "no parameters of its own"),
    ],
)
def test_bad_mode_input_is_one_line_and_exit_2(
    args: tuple[str, ...], needle: str, tmp_path: Path
) -> None:
    r = _cli(*args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and needle in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_tune_mode_scalar_searches_its_own_parameters(tmp_path: Path) -> None:
    """`tune --mode scalar`: its default space, trials of S and scalar, its metric as value."""
    from dsteleop.app.tune import driver
    from dsteleop.app.tune.objective import Objective

    settings = driver.TuneSettings(
        Objective(mode="scalar"), parse_space([], "scalar"), sampler="random", seed=0,
        batch=StudyBatch(2, 0, "scalar"),
    )  # fmt: skip
    assert [d.name for d in settings.space] == ["scalar.cap", "scalar.scale"]
    assert "maximise scalar's ratio of agreement" in settings.objective.statement()
    again = driver.TuneSettings.from_dict(settings.to_dict())
    assert again.mode == "scalar" and again.batch == settings.batch
    old = {k: v for k, v in settings.to_dict().items() if k != "mode"}  # a study made before
    old["space"] = list(default_space("DS"))
    assert driver.TuneSettings.from_dict(old).mode == "DS"
    study = driver.open_study(tmp_path, settings, resume=False)
    recs = driver.run_trials(study, settings, driver.LocalExecutor(), 2)
    assert [r.state for r in recs] == ["COMPLETE", "COMPLETE"], [r.error for r in recs]
    for r in recs:
        assert set(r.params) == {"scalar.cap", "scalar.scale"}
        assert 0.2 <= r.params["scalar.cap"] <= 1.0
        assert r.value == r.metrics["study.scalar.agreement"]
        assert r.constraints == (
            r.metrics["study.S.successes"] - r.metrics["study.scalar.successes"],
        )
    with pytest.raises(ConfigError, match="S is the reference"):
        Objective(mode="S")
