"""The belief over candidate goals (`arbitration/belief.py`) and the modes that read its
confidence (`DSC`, `conf_scalar`): a simulated person reaching (noisily) for one of three
candidates is recognised at a stated rate over seeds, a change of mind is followed, the
floor holds after long evidence, the confidence per dimension is high where the candidates
agree and low where they do not, c = 1 reduces DSC to DS and conf_scalar to scalar, both
modes reach every consumer, and bad parameters are one line."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dsteleop.app.study.batch import run_chunk
from dsteleop.app.study.planar import SimConfig, all_modes
from dsteleop.app.tune.space import default_space, parse_space
from dsteleop.app.viewer.server import mode_names
from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    HandState,
    Mode,
    RowModes,
    make_arbiter,
    so3_exp,
)
from dsteleop.arbitration.belief import BeliefParams, GoalBelief
from dsteleop.errors import ConfigError

DT = 1.0 / 30.0
F = 2
D = 6 + F
#: The candidates: three utensils side by side in a holder, 8 cm apart along y, the same x,
#: z, orientation and grasp (they agree in every dimension but y).
Y_M = (-0.08, 0.0, 0.08)


def _candidates(y: tuple[float, ...] = Y_M, x: tuple[float, ...] | None = None) -> HandState:
    K = len(y)
    xs = x or (0.55,) * K
    p = np.array([[xs[k], y[k], 0.12] for k in range(K)])
    return HandState(p, np.broadcast_to(np.eye(3), (K, 3, 3)).copy(), np.full((K, F), 0.3))


def _belief(sigma_m: float = 0.005, **params: float) -> GoalBelief:
    return GoalBelief(_candidates(), np.full((3, D), sigma_m), BeliefParams(**params))


def _person(
    rng: np.random.Generator,
    goals_p: np.ndarray,
    ticks: int,
    switch: int | None = None,
    new_goals_p: np.ndarray | None = None,
) -> list[HandState]:
    """n simulated people (one per row of goals_p), each reaching from a random start for
    its goal at 0.15 m/s (+-30 % per tick), its heading wandering (an Ornstein-Uhlenbeck
    perturbation of the unit direction, std ~0.4, 0.5 s), observed with 1 mm of tremor and
    0.02 rad of rotation noise; from tick `switch` on it reaches for `new_goals_p`."""
    n = goals_p.shape[0]
    x = np.stack([rng.uniform(0.22, 0.28, n), rng.uniform(-0.05, 0.05, n), np.full(n, 0.3)], 1)
    wander = np.zeros((n, 3))
    out = []
    for t in range(ticks):
        g = goals_p if switch is None or t < switch or new_goals_p is None else new_goals_p
        to = g - x
        dist = np.linalg.norm(to, axis=1, keepdims=True)
        wander += -wander * DT / 0.5 + rng.normal(0.0, 0.6 * math.sqrt(DT), (n, 3))
        u = to / np.maximum(dist, 1e-9) + wander
        u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
        x = x + u * np.minimum(0.15 * DT * rng.uniform(0.7, 1.3, (n, 1)), dist)
        obs = x + rng.normal(0.0, 0.001, (n, 3))
        out.append(HandState(obs, so3_exp(rng.normal(0.0, 0.02, (n, 3))), np.ones((n, F))))
    return out


def _run(belief: GoalBelief, path: list[HandState]) -> list[np.ndarray]:
    b = belief.initial(path[0].batch[0])
    out = [b]
    for t in range(1, len(path)):
        b = belief.update(b, path[t], path[t - 1])
        out.append(b)
    return out


# --- the belief -------------------------------------------------------------------------------


def test_the_belief_finds_the_persons_goal_at_a_stated_rate() -> None:
    """200 simulated people (one per row, seeded), each reaching for one of three candidates
    8 cm apart: the MAP is their goal in >= 82 % of them after 2.5 s and in >= 87 % after
    3.5 s, from 1/3 by chance; after 1 s it already beats chance (>= 55 %). Measured with
    generator seeds 0-5: 66-69 % at 1 s, 88-94 % at 2.5 s, 91-97 % at 3.5 s (seed 0: 69, 94,
    97 %)."""
    rng = np.random.default_rng(0)
    n = 200
    gb = _belief()
    goal = rng.integers(0, 3, n)
    beliefs = _run(gb, _person(rng, gb.goals.position[goal], 106))
    rate = {s: float(np.mean(beliefs[round(s / DT)].argmax(1) == goal)) for s in (1.0, 2.5, 3.5)}
    assert rate[1.0] >= 0.55 and rate[2.5] >= 0.82 and rate[3.5] >= 0.87, rate


def test_a_person_who_changes_their_mind_is_followed() -> None:
    """Reaching for one candidate for 1.5 s, then for another: within 1.5 s of the change the
    MAP is the new goal in >= 80 % of 200 people (measured 94.5 %), and the old one in <= 10 %
    (2 %); at the change it leaned the first way (73.5 %)."""
    rng = np.random.default_rng(1)
    n = 200
    gb = _belief()
    goal = rng.integers(0, 3, n)
    other = (goal + rng.integers(1, 3, n)) % 3
    switch = 45
    path = _person(rng, gb.goals.position[goal], 91, switch, gb.goals.position[other])
    beliefs = _run(gb, path)
    before = float(np.mean(beliefs[switch].argmax(1) == goal))
    after = beliefs[switch + 45].argmax(1)
    assert before >= 0.5, before  # it had leaned the first way
    assert np.mean(after == other) >= 0.80 and np.mean(after == goal) <= 0.10


@pytest.mark.parametrize("beta", [1.0, 100.0])
def test_the_floor_holds_after_long_evidence(beta: float) -> None:
    """20 s at the goal and pushing past it (600 ticks), at any beta: no probability is ever
    below epsilon, the beliefs sum to 1, and the MAP is bounded by 1 - (K - 1) eps."""
    rng = np.random.default_rng(2)
    eps = 0.02
    gb = _belief(beta=beta, epsilon=eps)
    n = 20
    goal = rng.integers(0, 3, n)
    path = _person(rng, gb.goals.position[goal], 600)
    # pushing on past the goal along its own side, 2 mm a tick, for the last 200 ticks
    for t in range(400, 600):
        side = np.zeros((n, 3))
        side[:, 1] = np.sign(gb.goals.position[goal, 1] + 1e-9) * 0.002 * (t - 399)
        path[t] = HandState(path[t].position + side, path[t].rotation, path[t].openness)
    for b in _run(gb, path):
        assert b.min() >= eps - 1e-12
        np.testing.assert_allclose(b.sum(1), 1.0, rtol=0, atol=1e-12)
        assert b.max() <= 1.0 - 2 * eps + 1e-12


def test_a_still_hand_keeps_the_belief_it_earned() -> None:
    """No motion is no evidence: the belief does not drift (the floor leaves it as it is)."""
    gb = _belief()
    b = np.array([[0.7, 0.2, 0.1]])
    X = HandState(np.array([[0.4, 0.0, 0.2]]), np.eye(3)[None], np.ones((1, F)))
    for _ in range(300):
        b = gb.update(b, X, X)
    np.testing.assert_allclose(b, [[0.7, 0.2, 0.1]], atol=1e-12)


def test_candidates_per_row_equal_shared_candidates() -> None:
    rng = np.random.default_rng(3)
    shared = _belief()
    per_row = GoalBelief(
        HandState(*(np.broadcast_to(a, (5, *a.shape)).copy() for a in
                    (shared.goals.position, shared.goals.rotation, shared.goals.openness))),
        np.full((5, 3, D), 0.005),
    )  # fmt: skip
    path = _person(rng, shared.goals.position[rng.integers(0, 3, 5)], 40)
    for a, b in zip(_run(shared, path), _run(per_row, path), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    c1, c2 = shared.confidence(a), per_row.confidence(b)
    np.testing.assert_allclose(c1.per_dim, c2.per_dim, atol=1e-12)
    np.testing.assert_array_equal(
        shared.goal_of(c1.map_index).position, per_row.goal_of(c2.map_index).position
    )


def test_the_model_of_some_rows_is_the_model_built_on_those_rows() -> None:
    """`GoalBelief.take` (the study drops the rows whose trial ended) selects the tables it
    computed; a model built on the kept rows alone gives the same numbers to the last bit."""
    rng = np.random.default_rng(11)
    n, K = 6, 3
    p = np.stack([_candidates().position + rng.normal(0.0, 0.01, (K, 3)) for _ in range(n)])
    R = so3_exp(rng.normal(0.0, 0.2, (n, K, 3)))
    goals = HandState(p, R, rng.uniform(0.0, 1.0, (n, K, F)))
    sigma = rng.uniform(0.001, 0.02, (n, K, D))
    prior = rng.uniform(0.5, 1.5, (n, K))
    model = GoalBelief(goals, sigma, BeliefParams(beta=2.0), prior=prior)
    keep = np.array([True, False, True, True, False, True])
    taken = model.take(keep)
    built = GoalBelief(goals.take(keep), sigma[keep], BeliefParams(beta=2.0), prior=prior[keep])
    m = int(keep.sum())
    X0 = HandState(p[keep, 0], R[keep, 1], rng.uniform(0.0, 1.0, (m, F)))
    X1 = HandState(p[keep, 2] + 0.01, R[keep, 0], rng.uniform(0.0, 1.0, (m, F)))
    np.testing.assert_array_equal(taken.agreement, built.agreement)
    np.testing.assert_array_equal(taken.cost_to_go(X1), built.cost_to_go(X1))
    b_taken = taken.update(taken.initial(m), X1, X0)
    b_built = built.update(built.initial(m), X1, X0)
    np.testing.assert_array_equal(b_taken, b_built)
    c_taken, c_built = taken.confidence(b_taken), built.confidence(b_built)
    for a, b in zip(c_taken, c_built, strict=True):
        np.testing.assert_array_equal(a, b)
    kept, rows = goals.take(keep), (np.arange(m), c_built.map_index)
    picked = HandState(kept.position[rows], kept.rotation[rows], kept.openness[rows])
    for G1, G2 in ((taken.goal_of(c_taken.map_index), built.goal_of(c_built.map_index)),
                   (taken.goal_of(c_taken.map_index), picked)):  # fmt: skip
        np.testing.assert_array_equal(G1.position, G2.position)
        np.testing.assert_array_equal(G1.rotation, G2.rotation)
        np.testing.assert_array_equal(G1.openness, G2.openness)
    # Every row's trial ended (the study's last step): a model of no rows, which still answers.
    none = model.take(np.zeros(n, dtype=bool))
    assert none.agreement.shape == (0, K, K, D)
    X_none = HandState(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, F)))
    assert none.cost_to_go(X_none).shape == (0, K)
    with pytest.raises(ConfigError, match="one set per row"):
        _belief().take(np.array([True]))


# --- the confidence per dimension ---------------------------------------------------------------


def test_confidence_is_high_where_the_candidates_agree_and_low_where_they_do_not() -> None:
    """Undecided among three candidates that differ only in y: c is ~1 in x, z, rotation and
    fingers and ~1/3 in y (only the MAP agrees with itself there); decided, c_y -> 1 - 2 eps."""
    gb = _belief(sigma_m=0.0)
    c = gb.confidence(gb.initial(1))
    assert c.per_dim[0, 1] == pytest.approx(1 / 3)
    assert np.delete(c.per_dim[0], 1) == pytest.approx(np.ones(D - 1))
    assert c.joint[0] == pytest.approx(1 / 3)
    decided = gb.confidence(np.array([[0.01, 0.98, 0.01]]))
    assert decided.map_index[0] == 1 and decided.per_dim[0, 1] == pytest.approx(0.98)
    # Two of three agree in x (4 mm apart, within the 2 cm tolerance), the third is 10 cm off.
    gx = GoalBelief(_candidates(x=(0.55, 0.554, 0.65)), np.zeros((3, D)))
    cx = gx.confidence(np.array([[0.45, 0.45, 0.10]]))
    assert cx.per_dim[0, 0] == pytest.approx(0.90) and cx.per_dim[0, 1] == pytest.approx(0.45)


def test_the_goals_own_uncertainty_lowers_its_dimensions_confidence() -> None:
    """A certain belief over one goal known up to sigma in x (a camera's depth) and sigma / 4
    in y: c_i = erf(s_i / (sqrt 2 sigma_i)), so c_x falls with sigma_x and c_y stays high."""
    s = BeliefParams().scale_m
    for sigma in (0.005, 0.02, 0.05):
        sig = np.zeros((1, D))
        sig[0, 0], sig[0, 1] = sigma, sigma / 4
        one = GoalBelief(_candidates(y=(0.0,)), sig, BeliefParams(epsilon=0.1))
        c = one.confidence(one.initial(1)).per_dim[0]
        assert c[0] == pytest.approx(math.erf(s / (math.sqrt(2) * sigma)))
        assert c[1] == pytest.approx(math.erf(s / (math.sqrt(2) * sigma / 4)))
        assert c[2] == 1.0
    assert math.erf(s / (math.sqrt(2) * 0.05)) < 0.35  # 5 cm of depth error: little trust in x


# --- the modes --------------------------------------------------------------------------------


def _states(rng: np.random.Generator, M: int) -> HandState:
    return HandState(
        rng.uniform(-0.3, 0.3, (M, 3)), so3_exp(rng.normal(0.0, 0.8, (M, 3))),
        rng.uniform(0.0, 1.0, (M, F)),
    )  # fmt: skip


def _inputs(rng: np.random.Generator, M: int, **extra: object) -> ArbitrationInput:
    S = [_states(rng, M) for _ in range(7)]
    return ArbitrationInput(
        X_human=S[0], X_human_prev=S[1], X_human_start=S[2], X_current=S[3], X_prev=S[4],
        X_start=S[5], X_goal=S[6], dt=DT, **extra,  # type: ignore[arg-type]
    )  # fmt: skip


@pytest.mark.parametrize(("mode", "twin"), [("DSC", "DS"), ("conf_scalar", "scalar")])
def test_confidence_one_reduces_to_ds_and_to_scalar_to_the_last_bit(mode: str, twin: str) -> None:
    """c = 1 (None, or ones given), at any DSC.power: DSC is DS and conf_scalar (threshold
    0) is scalar, every output equal, through DS's windows; with caps / cap set alike."""
    rng = np.random.default_rng(4)
    M = 40
    own = {"DSC": {"DSC.power": 2.5, "DSC.cap_rotation": 0.6},
           "conf_scalar": {"conf_scalar.cap": 0.7, "conf_scalar.scale": 1.5}}[mode]  # fmt: skip
    same = {
        "DSC": {"DS.cap_rotation": 0.6},
        "conf_scalar": {"scalar.cap": 0.7, "scalar.scale": 1.5},
    }
    cfg = ArbitrationConfig(window=3).replace(**own, **same[mode])
    arbs = {m: make_arbiter(m, cfg) for m in (mode, twin)}
    for confidence in (None, np.ones((M, D))):
        fs = {m: a.initial_state(D, (M,)) for m, a in arbs.items()}
        for _ in range(5):
            inp = _inputs(rng, M)
            told = inp
            if confidence is not None:
                told = dataclasses.replace(inp, confidence=confidence, confidence_joint=np.ones(M))
            fs[mode], a = arbs[mode].step(fs[mode], told)
            fs[twin], b = arbs[twin].step(fs[twin], inp)
            for name in STEP_ARRAYS:
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
            np.testing.assert_array_equal(a.X_next.rotation, b.X_next.rotation)


def test_dsc_gives_the_person_the_dimensions_the_robot_is_unsure_of() -> None:
    """Confidence 0 in y, 1 elsewhere: DSC's alpha equals DS's in every other dimension, and
    in y it is DS's eq (8) with P(R_y) = 0 (never above DS's there); in a mixed batch each
    row is what its mode gives alone."""
    rng = np.random.default_rng(5)
    M = 30
    c = np.ones((M, D))
    c[:, 1] = 0.0
    cfg = ArbitrationConfig(window=1)
    dsc, ds = make_arbiter("DSC", cfg), make_arbiter("DS", cfg)
    inp = _inputs(rng, M, confidence=c)
    _, a = dsc.step(dsc.initial_state(D, (M,)), inp)
    _, b = ds.step(ds.initial_state(D, (M,)), inp)
    others = [i for i in range(D) if i != 1]
    np.testing.assert_array_equal(a.alpha[:, others], b.alpha[:, others])
    np.testing.assert_allclose(a.alpha[:, 1], np.clip(b.P_human[:, 1] * (1 - b.B[:, 1]), 0, 1))
    assert (a.alpha[:, 1] <= b.alpha[:, 1] + 1e-12).all() and (a.P_robot[:, 1] == 0).all()
    # a mixed batch of DSC, DS, conf_scalar, scalar rows
    modes = [Mode.DSC, Mode.DS, Mode.CONF_SCALAR, Mode.SCALAR] * 5
    M = len(modes)
    c = rng.uniform(0.0, 1.0, (M, D))
    cj = rng.uniform(0.0, 1.0, M)
    mixed = make_arbiter(Mode.DS, ArbitrationConfig(window=3))
    fs = mixed.initial_state(D, (M,))
    singles = {m: make_arbiter(m, ArbitrationConfig(window=3)) for m in set(modes)}
    fss = {m: s.initial_state(D, (M,)) for m, s in singles.items()}
    for _ in range(4):
        inp = _inputs(rng, M, confidence=c, confidence_joint=cj)
        fs, out = mixed.step(fs, inp, RowModes.of(modes))
        for m, arb in singles.items():
            fss[m], alone = arb.step(fss[m], inp)
            idx = [k for k, mk in enumerate(modes) if mk is m]
            for name in STEP_ARRAYS:
                np.testing.assert_array_equal(getattr(out, name)[idx], getattr(alone, name)[idx])


def test_conf_scalar_is_one_alpha_scaled_by_the_ramp_of_the_joint_confidence() -> None:
    rng = np.random.default_rng(6)
    M = 50
    cj = rng.uniform(0.0, 1.0, M)
    cfg = ArbitrationConfig().replace(**{"conf_scalar.threshold": 0.4, "conf_scalar.cap": 0.8})
    inp = _inputs(rng, M, confidence_joint=cj)
    arb, ref = (
        make_arbiter("conf_scalar", cfg),
        make_arbiter("scalar", cfg.replace(**{"scalar.cap": 0.8})),
    )
    _, a = arb.step(arb.initial_state(D, (M,)), inp)
    _, b = ref.step(ref.initial_state(D, (M,)), inp)
    ramp = np.clip((cj - 0.4) / 0.6, 0.0, 1.0)
    np.testing.assert_allclose(a.alpha, b.alpha * ramp[:, None], rtol=1e-12, atol=1e-15)
    assert (a.alpha == a.alpha[:, :1]).all()  # one alpha for every dimension


def test_the_belief_drives_dsc_end_to_end() -> None:
    """A tick as the loop will make it: the belief's MAP is X_goal, its confidence is DSC's;
    undecided in y, the robot's authority in y is below DS's and equal elsewhere."""
    gb = _belief(sigma_m=0.0)
    b = gb.initial(1)
    conf = gb.confidence(b)
    goal = gb.goal_of(conf.map_index)
    rng = np.random.default_rng(7)
    X = _states(rng, 1)
    near = HandState(goal.position + 0.01, goal.rotation, goal.openness)
    inp = ArbitrationInput(
        X_human=near, X_human_prev=X, X_human_start=X, X_current=near, X_prev=X, X_start=X,
        X_goal=goal, dt=DT, confidence=conf.per_dim, confidence_joint=conf.joint,
    )  # fmt: skip
    _, a = make_arbiter("DSC").step(make_arbiter("DSC").initial_state(D, (1,)), inp)
    _, d = make_arbiter("DS").step(make_arbiter("DS").initial_state(D, (1,)), inp)
    assert a.alpha[0, 1] < d.alpha[0, 1]
    np.testing.assert_array_equal(a.alpha[0, [0, 2]], d.alpha[0, [0, 2]])


# --- every consumer, and bad input ------------------------------------------------------------


@pytest.mark.parametrize("name", ["DSC", "conf_scalar"])
def test_the_confidence_modes_reach_every_consumer(name: str) -> None:
    mode = Mode.parse(name)
    assert mode in list(Mode) and name in mode_names()  # the registry, the viewer's dropdown
    # The study runs it when asked, not by default: its worlds tell the robot its goal.
    assert mode.spec.reads_confidence and mode not in all_modes()
    assert mode not in SimConfig().modes
    space = default_space(name)
    assert any(s.startswith(f"{name}.") for s in space)
    assert {d.name for d in parse_space([], name)} >= {s.split("=")[0] for s in space}
    cfg = ArbitrationConfig()
    own = {k: v for k, v in cfg.to_dict().items() if k.startswith(f"{name}.")}
    assert own and ArbitrationConfig.from_json(cfg.to_json()) == cfg
    assert cfg.params_of(name) is not None


def test_the_study_runs_the_confidence_modes() -> None:
    cfg = SimConfig(trajectories=3, modes=(Mode.S, Mode.DSC, Mode.CONF_SCALAR), max_paths=0)
    chunk = run_chunk(cfg, [0, 1, 2])
    for name in ("DSC", "conf_scalar"):
        res = chunk.modes[name]
        assert res.success.shape == (3 * cfg.attempts,) and np.all(res.time_s > 0)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: BeliefParams(beta=0.0), r"belief\.beta must be in \(0, 100\]"),
        (lambda: BeliefParams(beta=float("nan")), r"belief\.beta"),
        (lambda: BeliefParams(epsilon=0.5), r"belief\.epsilon must be in \(0, 0\.25\]"),
        (lambda: BeliefParams(scale_m=-0.01), r"belief\.scale_m"),
        (lambda: BeliefParams(scale_rad=4.0), r"belief\.scale_rad"),
        (lambda: _belief().candidate_index("fork"), r"unknown candidate 'fork'"),
        (lambda: GoalBelief(_candidates(y=(0.0,) * 5), np.zeros((5, D)), BeliefParams(epsilon=0.2)),
         r"belief\.epsilon must be below 1/K"),
        (lambda: GoalBelief(_candidates(), np.zeros((2, D))), r"belief: sigma must be"),
        (lambda: GoalBelief(_candidates(), -np.ones((3, D))), r"sigma must be finite and >= 0"),
        (lambda: GoalBelief(_candidates(), np.zeros((3, D)), prior=np.array([1.0, 0.0, 1.0])),
         r"prior must be"),
        (lambda: ArbitrationConfig().replace(**{"DSC.power": -1.0}),
         r"DSC\.power must be in \[0, 10\]"),
        (lambda: ArbitrationConfig().replace(**{"DSC.cap": 0.0}), r"DSC\.cap_translation"),
        (lambda: ArbitrationConfig().replace(**{"conf_scalar.threshold": 1.0}),
         r"conf_scalar\.threshold must be in \[0, 0\.95\]"),
        (lambda: ArbitrationConfig().replace(**{"belief.beta": 0.0}),
         r"belief\.beta must be in \(0, 100\]"),
        (lambda: ArbitrationConfig.from_dict({"belief.bogus": 1.0}),
         r"unknown parameter belief\.bogus \(known: belief\.beta, belief\.epsilon"),
    ],
)  # fmt: skip
def test_bad_belief_and_mode_parameters_are_a_config_error(make: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as err:
        make()  # type: ignore[operator]
    assert "\n" not in str(err.value)


def test_a_confidence_out_of_range_or_shape_is_a_config_error() -> None:
    rng = np.random.default_rng(8)
    arb = make_arbiter("DSC")
    for bad, match in (
        ({"confidence": np.full((3, D), 1.5)}, r"confidence must be in \[0, 1\]"),
        ({"confidence": np.full((3, D), np.nan)}, r"confidence must be in \[0, 1\]"),
        ({"confidence": np.ones((2, D))}, r"confidence of shape"),
        ({"confidence_joint": -0.1}, r"confidence_joint must be in \[0, 1\]"),
    ):
        with pytest.raises(ConfigError, match=match):
            arb.step(arb.initial_state(D, (3,)), _inputs(rng, 3, **bad))


def test_the_belief_parameters_live_in_the_arbitration_config() -> None:
    """`belief.<field>` in the flat form (sessions, --param, --config, --space), round-tripped
    through JSON; a configuration without them (an older session) takes the defaults."""
    cfg = ArbitrationConfig().replace(**{"belief.beta": 2.5, "belief.scale_m": 0.03})
    assert cfg.belief == BeliefParams(beta=2.5, scale_m=0.03)
    flat = cfg.to_dict()
    assert {k for k in flat if k.startswith("belief.")} == {
        f"belief.{f.name}" for f in dataclasses.fields(BeliefParams)
    }
    assert ArbitrationConfig.from_json(cfg.to_json()) == cfg
    old = {k: v for k, v in flat.items() if not k.startswith("belief.")}
    assert ArbitrationConfig.from_dict(old).belief == BeliefParams()
    assert "belief" not in ArbitrationConfig.field_names()
    (dim,) = parse_space(["belief.beta=log:0.3:10"])
    assert dim.name == "belief.beta" and dim.log


@pytest.mark.parametrize(
    ("command", "param"),
    [("sim", "DSC.power=20"), ("sim", "conf_scalar.threshold=1"), ("sim", "belief.beta=200"),
     ("run", "belief.epsilon=0.5"), ("run", "belief.bogus=1"), ("serve", "belief.scale_m=0")],
)  # fmt: skip
def test_a_bad_mode_parameter_on_the_command_line_is_one_line_and_exit_2(
    command: str, param: str, tmp_path: Path
) -> None:
    extra = {
        "sim": ["--trajectories", "2", "--out", "o"],
        "run": ["--max-seconds", "1"],
        "serve": ["--source", "demo", "--port", "0"],
    }[command]
    r = subprocess.run(
        [sys.executable, "-m", "dsteleop.app.cli.main", command, "--param", param, *extra],
        capture_output=True, text=True, timeout=120, cwd=tmp_path, check=False,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and param.split("=", maxsplit=1)[0] in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
