"""The loop on the real robot, the real tracking pipeline and the synthetic hand.

Hands come from the kinematic hand model through the tracking pipeline (pose estimation,
One Euro filters, workspace mapping), the robot is the PyBullet kitchen, and time is a manual
clock, so every test runs as fast as the machine allows. Closed-loop physics: the checks are
tolerances and outcomes, never the last bits of a run.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.inputs.demo import DemoCamera
from dsteleop.app.inputs.tracked import TrackedHandInput
from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.loop.timing import ManualClock
from dsteleop.app.plants.kitchen import simulated_kitchen
from dsteleop.app.session.schema import Status, TickRecord
from dsteleop.arbitration import HandState, Mode
from dsteleop.robot.task import Phase
from dsteleop.tracking.mapping import WorkspaceMapping, human_openness
from dsteleop.tracking.pipeline import HandTracker
from dsteleop.tracking.synthetic import SyntheticSource

DT = 1.0 / 30.0


def min_jerk(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10 - 15 * u + 6 * u * u)


def scripted_loop(
    path: Callable[[HandState, float], HandState | None], mode: Mode = Mode.MANUAL
) -> TeleopLoop:
    """A loop whose operator's hand (robot frame, from the start state) follows `path`,
    seen by the virtual camera and tracked like a real one."""
    robot, task = simulated_kitchen(utensil="spoon", seed=0)
    task.reset()
    start = robot.reset(0.0).X
    camera = DemoCamera(start)

    def trajectory(t: float) -> tuple[HandState, NDArray[np.float64]] | None:
        X = path(start, t)
        if X is None:
            return None
        p, R = camera.mapping.to_camera(X)
        g5 = human_openness(X.openness)
        return HandState(p, R, g5), g5

    hand = TrackedHandInput.from_source(
        SyntheticSource(trajectory, fps=30.0), HandTracker(), WorkspaceMapping(), 0.0
    )
    return TeleopLoop(LoopConfig(mode=mode), hand, robot, task, clock=ManualClock(0.0))


def run_ticks(loop: TeleopLoop, seconds: float) -> list[TickRecord]:
    out = []
    for k in range(round(seconds / DT)):
        loop.clock.sleep_until(k * DT)
        out.append(loop.tick(k * DT))
    return out


def moved(start: HandState, dp: tuple[float, float, float], u: float) -> HandState:
    return HandState(start.position + np.asarray(dp) * u, start.rotation, np.ones(4))


def test_autonomous_mode_reaches_the_pick_and_the_place_goal() -> None:
    """Alpha = 1 through the whole loop: the palm comes to each goal the robot knows. As a
    rate over seeds (a grasp is closed-loop physics, whose last bits differ between CPUs)."""
    reached = 0
    for seed in (1, 2, 4):
        built = build(
            LoopOptions.of("demo", LoopConfig(mode=Mode.AUTONOMOUS), seed=seed), realtime=False
        )
        loop = built.loop
        records: list[TickRecord] = []
        try:
            for k in range(900):
                loop.clock.sleep_until(k * DT)
                records.append(loop.tick(k * DT))
                if loop.outcome:
                    break
        finally:
            loop.close()
        nearest = {
            phase: min(
                (
                    float(np.linalg.norm(r.X_current.position - r.X_goal.position))
                    for r in records
                    if r.phase is phase and r.X_goal is not None
                ),
                default=np.inf,
            )
            for phase in (Phase.PICK, Phase.PLACE)
        }
        assert nearest[Phase.PICK] < 0.015, (seed, nearest)
        reached += nearest[Phase.PLACE] < 0.015 and loop.outcome == "success"
    assert reached >= 2


def test_manual_mode_moves_the_robot_as_the_hand_moves() -> None:
    dp = (0.0, -0.10, -0.06)
    loop = scripted_loop(lambda s, t: moved(s, dp, min_jerk((t - 0.5) / 2.0)))
    try:
        records = run_ticks(loop, 4.0)
    finally:
        loop.close()
    tracked = [r for r in records if r.step is not None]
    assert len(tracked) > 100
    for r in tracked:
        assert r.step is not None
        np.testing.assert_array_equal(r.step.alpha, 0.0)
        np.testing.assert_allclose(r.step.U_out, r.step.U_human)
    first, last = tracked[0].X_human, tracked[-1].X_human
    assert first is not None and last is not None
    hand_move = last.position - first.position
    robot_move = records[-1].X_current.position - records[0].X_current.position
    np.testing.assert_allclose(hand_move, dp, atol=0.006)
    np.testing.assert_allclose(robot_move, hand_move, atol=0.006)


def test_ds_in_the_loop_leaves_an_unused_axis_to_the_operator() -> None:
    """The operator moves down only; the robot's goal also lies along -x. DS keeps alpha_x
    low and lets alpha_z rise; S has one alpha for all."""

    def down(s: HandState, t: float) -> HandState:
        return moved(s, (0.0, 0.0, -0.19), min_jerk((t - 0.3) / 3.0))

    results = {}
    for mode in (Mode.DS, Mode.S):
        loop = scripted_loop(down, mode)
        try:
            results[mode] = [r.step for r in run_ticks(loop, 4.0) if r.step is not None]
        finally:
            loop.close()
    ds, s = results[Mode.DS], results[Mode.S]
    i_x, i_z = 0, 2
    early_z = np.mean([x.alpha[i_z] for x in ds[5:20]])
    late = ds[-10:]
    assert np.mean([x.alpha[i_x] for x in late]) < 0.35
    assert np.mean([x.alpha[i_z] for x in late]) > early_z + 0.3
    assert all(np.ptp(x.alpha) == 0.0 for x in s)
    assert np.mean([x.alpha[i_z] - x.alpha[i_x] for x in late]) > 0.3
    v_max = LoopConfig().arbitration.v_max(4)

    def cos_dist(steps: list) -> float:  # type: ignore[type-arg]
        v = np.array([x.U_human for x in steps]) / v_max
        w = np.array([x.U_out for x in steps]) / v_max
        ok = (np.linalg.norm(v, axis=1) > 1e-6) & (np.linalg.norm(w, axis=1) > 1e-6)
        c = (v[ok] * w[ok]).sum(1) / (np.linalg.norm(v[ok], axis=1) * np.linalg.norm(w[ok], axis=1))
        return float(np.mean(1 - c))

    assert cos_dist(ds) < cos_dist(s)  # DS follows the operator more closely than S


def test_a_hidden_hand_halts_the_simulated_robot() -> None:
    def path(s: HandState, t: float) -> HandState | None:
        return None if t >= 1.5 else moved(s, (0.0, -0.08, -0.04), min(t / 1.5, 1.0))

    loop = scripted_loop(path)
    try:
        records = run_ticks(loop, 2.5)
    finally:
        loop.close()
    p = np.array([r.X_current.position for r in records])
    t = np.array([r.t_s for r in records])
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / DT
    assert speed[(t[1:] > 1.0) & (t[1:] < 1.4)].min() > 0.01
    assert speed[t[1:] > 1.5 + 0.2].max() < 2e-3  # within 0.2 s of the last fresh sample
    assert all(r.status is Status.LOST for r in records if r.t_s > 1.55)
