"""The teleoperation loop on the real robot, real tracking pipeline and the synthetic hand.

Hands come from the kinematic hand model through the tracking pipeline (pose estimation,
One Euro filters, workspace mapping), the robot is the PyBullet kitchen, and time is a manual
clock, so every test is deterministic and runs as fast as the machine allows.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.demo import DemoCamera, human_openness
from dsteleop.app.hand_input import TrackedHandInput
from dsteleop.app.loop import LoopConfig, LostPolicy, TeleopLoop
from dsteleop.app.observers import Snapshot
from dsteleop.app.plant import KitchenPlant
from dsteleop.app.setup import Setup, build
from dsteleop.app.timing import ManualClock
from dsteleop.arbitration import HandState, Mode
from dsteleop.tracking.mapping import WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker
from dsteleop.tracking.synthetic import SyntheticSource
from dsteleop.tracking.types import HandSample

DT = 1.0 / 30.0
Path_ = Callable[[float], HandState | None]


def min_jerk(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10 - 15 * u + 6 * u * u)


def scripted_loop(
    path: Callable[[HandState, float], HandState | None],
    mode: Mode = Mode.MANUAL,
    policy: LostPolicy = LostPolicy.HALT,
    corrupt: Callable[[HandSample], HandSample] | None = None,
) -> TeleopLoop:
    """A loop whose operator's hand (robot frame, from the start state) follows `path`."""
    plant = KitchenPlant("spoon", seed=0)
    start = plant.reset()
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
    if corrupt is not None:
        inner = hand._latest

        def latest(now: float) -> HandSample | None:
            s = inner(now)
            return None if s is None else corrupt(s)

        hand._latest = latest
    cfg = LoopConfig(mode=mode, lost_policy=policy)
    return TeleopLoop(cfg, hand, plant, clock=ManualClock(0.0))


def run_ticks(loop: TeleopLoop, seconds: float, t0: float = 0.0) -> list[Snapshot]:
    out = []
    for k in range(round(seconds / DT)):
        t = t0 + k * DT
        loop.clock.sleep_until(t)
        out.append(loop.tick(t))
    return out


def moved(start: HandState, dp: tuple[float, float, float], u: float, g: float = 1.0) -> HandState:
    return HandState(start.position + np.asarray(dp) * u, start.rotation, np.full(4, g))


# --- the task ---------------------------------------------------------------------------


def test_autonomous_mode_reaches_the_pick_and_the_place_goal() -> None:
    built = build(
        Setup(source="demo", loop=LoopConfig(mode=Mode.AUTONOMOUS), realtime=False, seed=1)
    )
    snaps: list[Snapshot] = []
    sub = built.loop.broadcaster.subscribe()
    loop = built.loop
    try:
        dt = loop.config.dt_s
        for k in range(900):
            loop.clock.sleep_until(k * dt)
            loop.tick(k * dt)
            snap = sub.latest()
            assert snap is not None
            snaps.append(snap)
            if loop.outcome:
                break
        events = [e for _, e in loop.events_log]
    finally:
        loop.close()
    # The palm came to each goal the robot knows (the pick goal, then the place goal).
    for phase in ("pick", "place"):
        d = [
            np.linalg.norm(s.X_current.position - s.X_goal.position)
            for s in snaps
            if s.phase == phase
        ]
        assert min(d) < 0.015, (phase, min(d))
    assert any(e.startswith("grasp") for e in events), events
    assert loop.outcome == "success", events


def test_manual_mode_moves_the_robot_as_the_hand_moves() -> None:
    dp = (0.0, -0.10, -0.06)
    loop = scripted_loop(lambda s, t: moved(s, dp, min_jerk((t - 0.5) / 2.0)))
    try:
        snaps = run_ticks(loop, 4.0)
    finally:
        loop.close()
    tracked = [s for s in snaps if s.arbitrated]
    assert len(tracked) > 100
    for s in tracked:
        np.testing.assert_array_equal(s.alpha, 0.0)
        np.testing.assert_allclose(s.U_out, s.U_human)
    # The robot's achieved palm moved by the hand's motion (mapped), to a few millimetres.
    first, last = tracked[0].X_human, tracked[-1].X_human
    assert first is not None and last is not None
    hand_move = last.position - first.position
    robot_move = snaps[-1].X_current.position - snaps[0].X_current.position
    np.testing.assert_allclose(hand_move, dp, atol=0.006)
    np.testing.assert_allclose(robot_move, hand_move, atol=0.006)


def test_ds_in_the_loop_leaves_an_unused_axis_to_the_operator() -> None:
    """The operator moves down only; the robot's goal also lies along -x. DS keeps alpha_x
    low and lets alpha_z rise; S has one alpha for all."""
    dz = -0.19

    def down(s: HandState, t: float) -> HandState:
        return moved(s, (0.0, 0.0, dz), min_jerk((t - 0.3) / 3.0))

    results = {}
    for mode in (Mode.DS, Mode.S):
        loop = scripted_loop(down, mode)
        try:
            results[mode] = [s for s in run_ticks(loop, 4.0) if s.arbitrated]
        finally:
            loop.close()
    ds, s = results[Mode.DS], results[Mode.S]
    i_x, i_z = 0, 2
    early_z = np.mean([x.alpha[i_z] for x in ds[5:20]])
    late = ds[-10:]
    assert np.mean([x.alpha[i_x] for x in late]) < 0.35
    assert np.mean([x.alpha[i_z] for x in late]) > early_z + 0.3
    # S: one alpha for every dimension; DS: separate ones.
    assert all(np.ptp(x.alpha) == 0.0 for x in s)
    assert np.mean([x.alpha[i_z] - x.alpha[i_x] for x in late]) > 0.3

    # DS follows the operator more closely than S (the paper's cosine distance).
    def cos_dist(snaps: list[Snapshot]) -> float:
        v = np.array([x.U_human for x in snaps]) / loop.config.arbitration.v_max(4)
        w = np.array([x.U_out for x in snaps]) / loop.config.arbitration.v_max(4)
        ok = (np.linalg.norm(v, axis=1) > 1e-6) & (np.linalg.norm(w, axis=1) > 1e-6)
        c = (v[ok] * w[ok]).sum(1) / (np.linalg.norm(v[ok], axis=1) * np.linalg.norm(w[ok], axis=1))
        return float(np.mean(1 - c))

    assert cos_dist(ds) < cos_dist(s)


def test_mode_switch_while_running() -> None:
    loop = scripted_loop(lambda s, t: moved(s, (0.0, 0.0, -0.1), min_jerk(t / 3.0)), Mode.DS)
    try:
        run_ticks(loop, 0.5)
        loop.controls.set_mode("S")
        snap = run_ticks(loop, 0.2, t0=0.5)[-1]
    finally:
        loop.close()
    assert snap.mode == "S"
    assert np.ptp(snap.alpha) == 0.0


# --- stale input ------------------------------------------------------------------------


def u_cmd(s: Snapshot) -> NDArray[np.float64]:
    """The commanded action of a snapshot (TeleopLoop always sets it)."""
    assert s.U_cmd is not None
    return s.U_cmd


def palm_speeds(snaps: list[Snapshot]) -> NDArray[np.float64]:
    p = np.array([s.X_current.position for s in snaps])
    return np.linalg.norm(np.diff(p, axis=0), axis=1) / DT


@pytest.mark.parametrize("policy", [LostPolicy.HALT])
def test_hidden_hand_halts_the_robot_within_0_2_s_and_resumes_without_a_jump(
    policy: LostPolicy,
) -> None:
    hide_at, show_at = 1.5, 2.5
    v = np.array([0.0, -0.08, -0.04])  # m/s: the hand is moving when it disappears

    def path(s: HandState, t: float) -> HandState | None:
        if hide_at <= t < show_at:
            return None
        # Reappears 5 cm away from where it vanished: it moved while lost.
        extra = np.array([0.0, 0.0, 0.05]) if t >= show_at else 0.0
        p = s.position + v * min(max(t - 0.3, 0.0), 2.0) + extra
        return HandState(p, s.rotation, np.ones(4))

    loop = scripted_loop(path, Mode.MANUAL, policy)
    try:
        snaps = run_ticks(loop, 3.5)
    finally:
        loop.close()
    t = np.array([s.t_s for s in snaps])
    last_fresh = max(
        s.hand.t_capture_s
        for s in snaps
        if s.t_s < hide_at + 0.5 and s.hand and s.hand.X_human is not None
    )
    assert last_fresh == pytest.approx(hide_at - DT, abs=1e-6)
    speed = palm_speeds(snaps)  # speed[k] between ticks k and k+1
    moving_before = speed[(t[1:] > hide_at - 0.4) & (t[1:] < hide_at - 0.1)]
    assert moving_before.min() > 0.05  # the robot was really moving
    after = speed[(t[1:] >= last_fresh + 0.2) & (t[1:] < show_at)]
    assert after.max() < 1e-3, after  # stopped within 0.2 s of the last fresh sample
    lost = [s for s in snaps if hide_at + 0.01 < s.t_s < show_at]
    assert all(s.status == "lost" and s.reason == "no hand" for s in lost)
    assert all(not s.arbitrated for s in lost)
    # Back: no jump larger than one tick's motion at the velocity limit.
    v_max = loop.config.arbitration.v_max_mps
    back = speed[(t[1:] >= show_at) & (t[1:] < show_at + 0.5)]
    assert back.max() <= v_max * 1.05
    first_back = next(s for s in snaps if s.t_s >= show_at and s.arbitrated)
    np.testing.assert_allclose(first_back.U_human, 0.0, atol=1e-12)


def run_corrupted(corrupt: Callable[[HandSample], HandSample]) -> list[Snapshot]:
    """1.6 s of a manual move whose hand samples pass through `corrupt` first."""
    loop = scripted_loop(
        lambda s, t: moved(s, (0.0, -0.05, -0.05), min_jerk(t / 2.0)), Mode.MANUAL, corrupt=corrupt
    )
    try:
        return run_ticks(loop, 1.6)
    finally:
        loop.close()


def test_nan_in_the_hand_data_counts_as_stale() -> None:
    def corrupt(s: HandSample) -> HandSample:
        if s.t_capture_s >= 1.0:
            return dataclasses.replace(s, p_cam_palm_m=np.full(3, np.nan))
        return s

    snaps = run_corrupted(corrupt)
    late = [s for s in snaps if s.t_s > 1.05]
    assert all(s.status == "lost" and s.reason == "invalid hand data" for s in late)
    assert palm_speeds(snaps[-5:]).max() < 1e-3
    assert all(np.isfinite(s.X_current.position).all() for s in snaps)


def test_a_stalled_camera_is_detected_by_age() -> None:
    frozen: list[HandSample] = []

    def corrupt(s: HandSample) -> HandSample:
        # The camera delivers nothing new after 1 s: the same old sample keeps coming.
        if s.t_capture_s < 1.0:
            frozen[:] = [s]
            return s
        return frozen[0]

    snaps = run_corrupted(corrupt)
    last = frozen[0].t_capture_s
    for s in snaps:
        if s.t_s > last + 0.1 + 1e-6:
            assert s.status == "lost" and s.reason == "camera stalled"
        elif s.t_s > 0.2:
            assert s.status == "tracking"


def test_assist_policy_keeps_going_towards_the_goal_while_the_hand_is_lost() -> None:
    def path(s: HandState, t: float) -> HandState | None:
        return None if t > 0.5 else s

    loop = scripted_loop(path, Mode.DS, LostPolicy.ASSIST)
    try:
        snaps = run_ticks(loop, 3.0)
    finally:
        loop.close()
    goal = snaps[-1].X_goal.position
    assisting = [s for s in snaps if s.t_s > 0.7]
    assert all(s.status == "assist" for s in assisting)
    d = [float(np.linalg.norm(s.X_current.position - goal)) for s in assisting]
    assert d[-1] < d[0] - 0.05  # it kept going towards the goal
    # at reduced speed: the commanded speed is `assist_speed` of the policy's
    for s in assisting[:20]:
        np.testing.assert_allclose(u_cmd(s), s.U_robot * loop.config.assist_speed)
    assert (
        max(np.linalg.norm(u_cmd(s)[:3]) for s in assisting)
        <= loop.config.arbitration.v_max_mps * 0.5 + 1e-9
    )


def test_halt_policy_does_not_move_without_a_hand() -> None:
    loop = scripted_loop(lambda s, t: None, Mode.DS)
    try:
        snaps = run_ticks(loop, 1.0)
    finally:
        loop.close()
    assert all(s.status == "lost" and s.reason == "no hand" for s in snaps[3:])
    assert palm_speeds(snaps).max() < 2e-3
    assert math.isclose(float(np.linalg.norm(u_cmd(snaps[-1]))), 0.0)


def test_an_injected_input_delay_delays_the_robot() -> None:
    def path(s: HandState, t: float) -> HandState:
        return moved(s, (0.0, -0.1, 0.0), min_jerk((t - 0.5) / 1.5))

    runs = {}
    for delay in (0.0, 0.2):
        loop = scripted_loop(path, Mode.MANUAL)
        loop.config = dataclasses.replace(loop.config, input_delay_s=delay)
        assert isinstance(loop.hand, TrackedHandInput)
        loop.hand.input_delay_s = delay
        try:
            runs[delay] = run_ticks(loop, 3.0)
        finally:
            loop.close()
        assert loop.session_meta()["loop"]["input_delay_s"] == delay

    def y_at_half(snaps: list[Snapshot]) -> float:
        y = np.array([s.X_current.position[1] for s in snaps])
        y0, y1 = y[0], y[-1]
        return float(snaps[int(np.argmax(np.abs(y - y0) >= 0.5 * abs(y1 - y0)))].t_s)

    lag = y_at_half(runs[0.2]) - y_at_half(runs[0.0])
    assert lag == pytest.approx(0.2, abs=DT + 1e-6)


def test_a_slow_observer_only_misses_snapshots() -> None:
    loop = scripted_loop(lambda s, t: moved(s, (0.0, -0.05, 0.0), min_jerk(t)), Mode.DS)
    stalled = loop.broadcaster.subscribe()  # never reads
    reader = loop.broadcaster.subscribe()
    seen = []
    try:
        for k in range(60):
            t = k * DT
            loop.clock.sleep_until(t)
            loop.tick(t)
            if k % 10 == 9:
                snap = reader.latest()
                assert snap is not None
                seen.append(snap.tick)
    finally:
        loop.close()
    assert stalled.received == 60 and stalled.dropped == 59
    newest = stalled.latest()
    assert newest is not None and newest.tick == 59  # newest wins, one slot
    assert seen == [9, 19, 29, 39, 49, 59]
    assert reader.dropped == 60 - 6
