"""The disagreement world (`--world disagreement`, app/study/grasps.py, docs/operator.md):
two right grasps, the robot going to one, each person preferring one and adapting with its
own probability. A test per mechanism, the study's outcome structure, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsteleop.app.cli.main import main
from dsteleop.app.operator.person import Intention
from dsteleop.app.operator.world import Impairments
from dsteleop.app.study import batch, results
from dsteleop.app.study import planar as study_planar
from dsteleop.app.study import summary as study_summary
from dsteleop.app.study.grasps import Grasps, settle_after
from dsteleop.arbitration import HandState, Mode
from dsteleop.errors import ConfigError
from tests.test_operator_closed_loop import one_stage, operators, planar

WORLD = Impairments().replace(goal_sigma_m=0.0)


def config(n: int, **kw: object) -> study_planar.SimConfig:
    opts: dict[str, object] = {"trajectories": n, "grasps": Grasps(), "world": WORLD}
    opts["max_paths"] = 0
    opts.update(kw)
    return study_planar.SimConfig(**opts)  # type: ignore[arg-type]


# --- the world --------------------------------------------------------------------------------


def test_either_grasp_succeeds_and_neither_is_inside_the_others_tolerance() -> None:
    cfg = config(4)
    top, side = cfg.grasp_headings
    assert top == pytest.approx(math.pi / 4) and side == pytest.approx(-math.pi / 4)
    xy = np.tile(cfg.handle_xy_m, (4, 1))
    heading = np.array([top, side, (top + side) / 2, side - 0.36])
    got = study_planar.in_success_region(
        xy, heading, cfg.handle_xy_m, cfg.grasp_headings, 0.03, 0.35
    )
    assert got.tolist() == [True, True, False, False]
    # The default world has the one grasp: the side grasp fails there.
    one = study_planar.in_success_region(xy, heading, cfg.handle_xy_m, math.pi / 4, 0.03, 0.35)
    assert one.tolist() == [True, False, False, False]
    # Each agent's grasp lies outside the other's tolerance (task's 0.35 + person's 0.175).
    assert abs(top - side) > cfg.success_heading_rad + cfg.operator_tolerance_rad


def test_the_robot_goes_to_its_grasp_at_the_true_handle() -> None:
    for grasp, heading in (("top", math.pi / 4), ("side", -math.pi / 4)):
        cfg = config(3, grasps=Grasps(robot_grasp=grasp))
        for n in range(3):
            g = study_planar.robot_goal(cfg, n, 0)
            assert g[:2] == pytest.approx(cfg.handle_xy_m) and g[2] == pytest.approx(heading)


def test_the_share_of_people_who_prefer_the_robots_grasp() -> None:
    """The preference is a draw per person: the share over many people is the stated share
    (binomial, 5 sd), and each person aims for its own grasp's heading."""
    for share in (0.5, 0.2):
        cfg = config(2000, grasps=Grasps(prefer_robot_share=share))
        trials = [study_planar.sample_closed_trial(cfg, n) for n in range(cfg.trajectories)]
        prefers = np.array([t.grasp == 0 for t in trials])
        sd = math.sqrt(share * (1 - share) / prefers.size)
        assert abs(prefers.mean() - share) < 5 * sd
        for t in trials[:50]:
            assert t.operator_goal[2] == pytest.approx(cfg.grasp_headings[t.grasp])


def test_adaptability_gives_a_geometric_number_of_pauses() -> None:
    """Nikolaidis et al.'s bounded-memory adaptation: a switch with probability alpha at each
    disagreement, so the pause of the switch is geometric with mean 1 / alpha."""
    rng = np.random.default_rng(3)
    assert settle_after(0.99, 1.0, 10**6) == 1
    assert settle_after(0.01, 0.0, 10**6) == 10**6
    for alpha in (0.2, 0.5):
        k = np.array([settle_after(u, alpha, 10**6) for u in rng.random(20000)])
        assert k.min() == 1
        assert k.mean() == pytest.approx(1 / alpha, rel=0.05)
        assert (k == 1).mean() == pytest.approx(alpha, abs=0.02)
    # Per person: alpha from U(lo, hi), and the default world's people settle at the first.
    cfg = config(500, grasps=Grasps(adaptability=(0.2, 0.4)))
    alphas = np.array([study_planar.sample_closed_trial(cfg, n).adaptability for n in range(500)])
    assert alphas.min() >= 0.2 and alphas.max() <= 0.4 and np.ptp(alphas) > 0.15
    plain = study_planar.SimConfig(trajectories=20)
    assert {study_planar.sample_closed_trial(plain, n).settle_after for n in range(20)} == {1}


def test_a_person_keeps_its_way_until_its_own_pause_then_switches() -> None:
    """Against a robot that never turns, people who want another heading are resisted again
    and again; each switches to the robot's way at its own pause (1, 2, or never), never
    before, and the one that never switches keeps pushing until its patience runs out."""
    n = 9
    target = planar(0.3, 0.4, 0.5)
    it = one_stage(target, n)
    after = np.array(
        [
            1,
            1,
            1,
            2,
            2,
            2,
            study_planar.NEVER_SETTLES,
            study_planar.NEVER_SETTLES,
            study_planar.NEVER_SETTLES,
        ]
    )
    intention = Intention(
        it.targets, it.tolerance, it.mask, it.n_stages, it.turn_within_m,
        one_stage(planar(0.3, 0.4, 0.0), n).targets, np.tile([0.03, 0.35, 1.0], (n, 1, 1)),
        after,
    )  # fmt: skip
    op = operators(n, seed=5, intention=intention, patience_s=40.0)
    X = op.start
    op.observe(0.0, X)
    for k in range(1, round(45.0 / study_planar.SimConfig().dt_s) + 1):
        t = k / 30.0
        H = op.hand(t)
        X = HandState(H.position, X.rotation, H.openness)  # follows the position, never turns
        op.observe(t, X)
        assert np.array_equal(op.settled, op.pauses >= after)  # never before its own pause
        if op.done.all():
            break
    assert op.settled[:6].all() and not op.settled[6:].any()
    assert (op.pauses[6:] >= 3).all()  # it kept its way through pause after pause
    assert op.gave_up[6:].all() and op.committed[:6].all()


# --- the study in this world -------------------------------------------------------------------


def test_every_assisted_mode_can_succeed_without_noise_and_delay() -> None:
    """No built-in impossibility: without goal noise, delay or depth error, every mode
    succeeds for people who prefer the robot's grasp and for people who prefer the other."""
    cfg = config(60, world=Impairments.unimpaired())
    res = results.merge(cfg, [batch.run_chunk(cfg, list(range(cfg.trajectories)))])
    summary = study_summary.disagreement_summary(res)
    assert summary["people"]["prefers_robot_grasp"] > 15
    assert summary["people"]["prefers_other_grasp"] > 15
    for mode in (Mode.S, Mode.DS, Mode.SCALAR, Mode.MANUAL):
        for group in ("prefers_robot_grasp", "prefers_other_grasp"):
            assert summary["modes"][mode.value][group]["success_rate"]["estimate"] >= 0.3, (
                mode,
                group,
            )


def test_the_summary_separates_the_groups_and_where_they_ended() -> None:
    cfg = config(40, modes=(Mode.S, Mode.DS, Mode.MANUAL, Mode.AUTONOMOUS))
    res = results.merge(cfg, [batch.run_chunk(cfg, list(range(cfg.trajectories)))])
    out = study_summary.summarise(res)
    d = out["disagreement"]
    assert d["robot_grasp"] == "top" and out["config"]["grasps"]["robot_grasp"] == "top"
    people = d["people"]["prefers_robot_grasp"] + d["people"]["prefers_other_grasp"]
    assert people == cfg.trajectories
    auto = d["modes"]["autonomous"]
    # The robot alone ends in its own grasp; nobody ends in the side grasp under it.
    assert auto["prefers_other_grasp"]["successes_in"]["side"] == 0
    # Manual leaves people who prefer the side grasp their own way: some succeed there, and
    # nobody has to switch for lack of control of the heading.
    man = d["modes"]["manual"]["prefers_other_grasp"]
    assert man["successes_in"]["side"] > 0
    assert 0.0 <= man["switched_share"] <= auto["prefers_other_grasp"]["switched_share"]


def test_the_default_world_has_no_disagreement_block() -> None:
    cfg = study_planar.SimConfig(trajectories=4, max_paths=0, modes=(Mode.S, Mode.DS))
    out = study_summary.summarise(results.merge(cfg, [batch.run_chunk(cfg, [0, 1, 2, 3])]))
    assert "disagreement" not in out and "grasps" not in out["config"]


# --- bad input ---------------------------------------------------------------------------------


def test_grasps_are_validated() -> None:
    with pytest.raises(ConfigError, match="unknown grasp"):
        Grasps(robot_grasp="left")
    with pytest.raises(ConfigError, match="share"):
        Grasps(prefer_robot_share=1.2)
    with pytest.raises(ConfigError, match="adaptability"):
        Grasps(adaptability=(0.6, 0.4))
    with pytest.raises(ConfigError, match="would not disagree"):
        config(2, grasps=Grasps(separation_rad=0.4))


@pytest.mark.parametrize(
    "args",
    [
        ["--world", "elsewhere"],
        ["--world", "disagreement", "--robot-grasp", "left"],
        ["--world", "disagreement", "--prefer-robot-share", "-0.1"],
        ["--world", "disagreement", "--adaptability", "0.5"],
        ["--world", "disagreement", "--grasp-separation", "4"],
        ["--robot-grasp", "top"],
    ],
)
def test_bad_world_options_are_one_line_and_exit_2(
    args: list[str], tmp_path: object, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["sim", "--no-progress", "--trajectories", "2", "--out", f"{tmp_path}/o", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0]
