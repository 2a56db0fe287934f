"""Modes as plug-ins: a mode defined and registered here, in a test file, reaches the kernel's
mixed batches, the study, tune's spaces, replay's and the viewer's mode lists without an edit
to them; the scalar baseline is S at cap 1 and scale 1; a bad mode or mode parameter is one
line and exit code 2."""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.study.batch import run_chunk
from dsteleop.app.study.planar import SimConfig, all_modes
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
    from dsteleop.app.tasks.executor import LocalExecutor
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
    recs = driver.run_trials(study, settings, LocalExecutor(), 2)
    assert [r.state for r in recs] == ["COMPLETE", "COMPLETE"], [r.error for r in recs]
    for r in recs:
        assert set(r.params) == {"scalar.cap", "scalar.scale"}
        assert 0.05 <= r.params["scalar.cap"] <= 1.0
        assert r.value == r.metrics["study.scalar.agreement"]
        assert r.constraints == (
            r.metrics["study.S.successes"] - r.metrics["study.scalar.successes"],
        )
    with pytest.raises(ConfigError, match="S is the reference"):
        Objective(mode="S")


# --- DS's own authority caps (issue 31: the baselines' levers equal) -------------------------

#: `_outputs_digest()` with the code of commit 8b0c905 (before DS had caps and before
#: `human_reference`): regenerate by running that function on that commit.
DIGEST_BEFORE_CAPS = "8ede7deaab215e52d60bfd9a3d2f4644d684b5c841487eb68e717d7201e9cf66"


def _outputs_digest(cfg: ArbitrationConfig | None = None) -> str:
    """SHA-256 of every output of 12 ticks of a mixed batch of the built-in modes (3 random
    rows each, 2 fingers), closed loop on X_next, from a seeded generator (only API that the
    commit of DIGEST_BEFORE_CAPS has)."""
    import hashlib

    rng = np.random.default_rng(31)
    names = ("DS", "S", "manual", "autonomous", "scalar")
    modes = [Mode.parse(n) for n in names for _ in range(3)]
    M, F = len(modes), 2

    def states() -> HandState:
        return HandState(
            rng.uniform(-0.3, 0.3, (M, 3)), so3_exp(rng.normal(0.0, 0.8, (M, 3))),
            rng.uniform(0.0, 1.0, (M, F)),
        )  # fmt: skip

    arb = make_arbiter(Mode.DS, cfg)
    rows = RowModes.of(modes)
    fs = arb.initial_state(6 + F, (M,))
    X, goal, start, hand_start, hand_prev = states(), states(), states(), states(), states()
    prev = X
    h = hashlib.sha256()
    for _ in range(12):
        hand = states()
        inp = ArbitrationInput(
            X_human=hand, X_human_prev=hand_prev, X_human_start=hand_start, X_current=X,
            X_prev=prev, X_start=start, X_goal=goal, dt=1.0 / 30.0, X_ref=X,
        )  # fmt: skip
        fs, step = arb.step(fs, inp, rows)
        for name in STEP_ARRAYS:
            h.update(np.ascontiguousarray(getattr(step, name)).tobytes())
        for a in (step.X_next.position, step.X_next.rotation, step.X_next.openness):
            h.update(np.ascontiguousarray(a).tobytes())
        prev, X, hand_prev = X, step.X_next, hand
    return h.hexdigest()


def test_every_mode_at_the_defaults_is_bit_identical_to_before_the_caps() -> None:
    """DS's caps at 1.0 and human_reference="hand" change no output's last bit."""
    assert _outputs_digest() == DIGEST_BEFORE_CAPS
    explicit = ArbitrationConfig().replace(
        **{"DS.cap": 1.0, "human_reference": "hand", "scalar.cap": 1.0}
    )
    assert _outputs_digest(explicit) == DIGEST_BEFORE_CAPS
    capped = ArbitrationConfig().replace(**{"DS.cap_rotation": 0.5})
    assert _outputs_digest(capped) != DIGEST_BEFORE_CAPS  # the digest sees the caps


def test_ds_caps_multiply_each_groups_alpha_after_the_window() -> None:
    """alpha = cap_g * (eq 8 on its windows): the windows keep the uncapped alpha, so every
    tick's capped alpha is cap_g times the uncapped one to the last bit; B is DS's own."""
    rng = np.random.default_rng(7)
    M, F = 6, 3
    caps = {"DS.cap_translation": 0.3, "DS.cap_rotation": 0.6, "DS.cap_fingers": 0.9}
    free = make_arbiter(Mode.DS, ArbitrationConfig(window=4))
    capped = make_arbiter(Mode.DS, ArbitrationConfig(window=4).replace(**caps))
    cap = np.array([0.3] * 3 + [0.6] * 3 + [0.9] * F)
    fs_free, fs_cap = free.initial_state(6 + F, (M,)), capped.initial_state(6 + F, (M,))
    for _ in range(6):  # past the window
        inp = _input(rng, M, F)
        fs_free, a = free.step(fs_free, inp)
        fs_cap, b = capped.step(fs_cap, inp)
        np.testing.assert_array_equal(b.alpha, cap * a.alpha)
        for name in ("P_human", "P_robot", "B", "U_human", "U_robot"):
            np.testing.assert_array_equal(getattr(b, name), getattr(a, name))
        np.testing.assert_array_equal(fs_cap.alpha_window, fs_free.alpha_window)
        assert np.all(b.alpha <= cap)
        np.testing.assert_allclose(
            b.U_out, b.alpha * b.U_robot + (1 - b.alpha) * b.U_human, rtol=0, atol=1e-15
        )


def test_ds_cap_shorthand_sets_all_three_and_round_trips() -> None:
    cfg = ArbitrationConfig().replace(**{"DS.cap": 0.2})
    p = cfg.params_of("DS")
    assert (p.cap_translation, p.cap_rotation, p.cap_fingers) == (0.2, 0.2, 0.2)
    # A cap given by its own name wins over the shorthand.
    both = ArbitrationConfig.from_dict({"DS.cap": 0.2, "DS.cap_rotation": 0.7})
    assert both.params_of("DS").cap_rotation == 0.7 and both.params_of("DS").cap_fingers == 0.2
    d = both.to_dict()
    assert "DS.cap" not in d  # written as the parameters themselves
    assert (d["DS.cap_translation"], d["DS.cap_rotation"], d["DS.cap_fingers"]) == (0.2, 0.7, 0.2)
    assert ArbitrationConfig.from_dict(d) == both
    assert ArbitrationConfig.from_json(both.to_json()) == both
    old = ArbitrationConfig.from_dict({"kappa": 4.0})  # a session recorded before the caps
    assert old.params_of("DS").cap_translation == 1.0


@pytest.mark.parametrize(
    ("name", "value"),
    [("DS.cap", 1.5), ("DS.cap_rotation", 0.0), ("DS.cap_fingers", float("inf"))],
)
def test_a_bad_ds_cap_is_a_config_error(name: str, value: float) -> None:
    with pytest.raises(ConfigError, match=r"DS\.cap\w* must be in \(0, 1\]"):
        ArbitrationConfig().replace(**{name: value})


@pytest.mark.parametrize(
    ("command", "args"),
    [
        ("sim", ("--trajectories", "2", "--out", "o")),
        ("tune", ("--trials", "1", "--out", "o")),
        ("run", ("--source", "demo")),
        ("serve", ("--source", "demo")),
    ],
)
def test_every_command_with_param_accepts_ds_cap(command: str, args: tuple[str, ...]) -> None:
    """`--param DS.cap=0.2` through each command's own parser and checks (what it runs with)."""
    import importlib

    from dsteleop.app.cli.main import COMMANDS, build_parser

    parser = build_parser()
    module = importlib.import_module(COMMANDS[command][0])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    module.add_arguments(sub.choices[command])
    parsed = parser.parse_args([command, *args, "--param", "DS.cap=0.2"])
    cmd = module.command(parsed)
    if command == "sim":
        cfg = cmd.study.arbitration
    elif command == "tune":
        cfg = ArbitrationConfig.from_dict(cmd.plan.given["base"])
    else:
        cfg = cmd.options.loop.arbitration
    p = cfg.params_of("DS")
    assert (p.cap_translation, p.cap_rotation, p.cap_fingers) == (0.2, 0.2, 0.2)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("sim", "--trajectories", "2", "--param", "DS.cap=1.5", "--out", "o"), "DS.cap"),
        (("sim", "--trajectories", "2", "--param", "DS.cap_rotation=0", "--out", "o"), "DS.cap"),
        (("tune", "--trials", "1", "--param", "DS.cap=1.5", "--out", "o"), "DS.cap"),
        (("run", "--source", "demo", "--param", "DS.cap_rotation=0"), "DS.cap_rotation"),
        (("serve", "--source", "demo", "--param", "DS.cap=1.5"), "DS.cap"),
        (
            ("sim", "--trajectories", "2", "--param", "human_reference=foo", "--out", "o"),
            "human_reference",
        ),
    ],
)
def test_a_bad_ds_cap_or_reference_is_one_line_and_exit_2(
    args: tuple[str, ...], needle: str, tmp_path: Path
) -> None:
    r = _cli(*args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and needle in r.stderr, r.stderr


def test_ds_and_scalar_search_their_caps_over_one_range() -> None:
    ds = {d.name: d for d in parse_space([], "DS")}
    scalar = {d.name: d for d in parse_space([], "scalar")}
    assert "DS.cap_fingers" not in ds  # the planar study has no fingers
    for d in (ds["DS.cap_translation"], ds["DS.cap_rotation"], scalar["scalar.cap"]):
        assert (d.low, d.high, d.log) == (0.05, 1.0, False)


def test_a_mixed_study_batch_keeps_each_rows_caps() -> None:
    """The study's mixed batch (every_quantity=False, DS's and scalar's rows together): each
    row's actions are its mode's alone, with its own mode's cap."""
    rng = np.random.default_rng(9)
    modes = [Mode.DS, Mode.SCALAR, Mode.S] * 4
    M = len(modes)
    cfg = ArbitrationConfig(window=3).replace(**{"DS.cap": 0.4, "scalar.cap": 0.7})
    arb = make_arbiter(Mode.DS, cfg)
    rows = RowModes.of(modes)
    singles = {m: make_arbiter(m, cfg) for m in set(modes)}
    fs = arb.initial_state(10, (M,))
    fs_single = {m: a.initial_state(10, (M,)) for m, a in singles.items()}
    for _ in range(4):
        inp = _input(rng, M)
        fs, mixed = arb.step(fs, inp, rows, every_quantity=False)
        for m, single in singles.items():
            fs_single[m], alone = single.step(fs_single[m], inp)
            idx = [k for k, mk in enumerate(modes) if mk is m]
            for name in ("alpha", "U_out"):
                np.testing.assert_array_equal(getattr(mixed, name)[idx], getattr(alone, name)[idx])
    assert mixed.alpha[[k for k, m in enumerate(modes) if m is Mode.DS]].max() <= 0.4
    assert mixed.alpha[[k for k, m in enumerate(modes) if m is Mode.SCALAR]].max() <= 0.7
