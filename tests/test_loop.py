"""The loop's own logic against fakes of its ports: no PyBullet, no camera, no tracking.

The hand is a scripted path in the robot base frame (`fakes.ScriptedHand`), the robot a
kinematic fake and the task a two-segment fake (`fakes.fake_world`), on a manual clock, so every
test is exact and fast: staleness and the halt ramp, re-anchoring, the assist policy, the input
delay, the one-slot observers, mode and parameter changes, recording, the operator history.
`test_loop_kitchen.py` runs the same loop on the PyBullet robot and the real tracking.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dsteleop.app.loop import LoopConfig, LostPolicy, TeleopLoop
from dsteleop.app.loop import tick as loop_tick
from dsteleop.app.loop.timing import ManualClock
from dsteleop.app.ports import INVALID, ROBOT_LOST, ROBOT_STALE_S, HumanInput
from dsteleop.app.session.reader import read_session
from dsteleop.app.session.schema import Status, TickRecord
from dsteleop.app.session.writer import HISTORY_FILE, HistoryFile
from dsteleop.arbitration import HandState, Mode, OperatorHistory
from dsteleop.robot.task import Phase

from .fakes import DT, FakeRobot, ScriptedHand, fake_world, state

START = state((0.5, 0.3, 0.4))


def min_jerk(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10 - 15 * u + 6 * u * u)


def moving(dp: tuple[float, float, float], t0: float = 0.3, T: float = 2.0):
    def path(t: float) -> HandState:
        return HandState(
            START.position + np.asarray(dp) * min_jerk((t - t0) / T), START.rotation, np.ones(4)
        )

    return path


def make_loop(
    path, mode: Mode = Mode.MANUAL, policy: LostPolicy = LostPolicy.HALT, **kw
) -> TeleopLoop:
    hand = kw.pop("hand", None) or ScriptedHand(path, input_delay_s=kw.get("input_delay_s", 0.0))
    cfg = LoopConfig(mode=mode, lost_policy=policy, **kw)
    return TeleopLoop(cfg, hand, *fake_world(start=START), clock=ManualClock(0.0))


def run(loop: TeleopLoop, seconds: float, t0: float = 0.0) -> list[TickRecord]:
    out = []
    for k in range(round(seconds / DT)):
        t = t0 + k * DT
        loop.clock.sleep_until(t)
        out.append(loop.tick(t))
    return out


def speeds(records: list[TickRecord]) -> np.ndarray:
    p = np.array([r.X_current.position for r in records])
    return np.linalg.norm(np.diff(p, axis=0), axis=1) / DT


# --- tracking ---------------------------------------------------------------------------


def test_manual_mode_moves_the_robot_exactly_as_the_hand_moves() -> None:
    dp = (0.0, -0.10, -0.06)
    loop = make_loop(moving(dp))
    records = run(loop, 3.0)
    tracked = [r for r in records if r.step is not None]
    assert len(tracked) > 80 and all(r.status is Status.TRACKING for r in tracked)
    for r in tracked:
        assert r.step is not None
        np.testing.assert_array_equal(r.step.alpha, 0.0)
        np.testing.assert_allclose(r.step.U_out, r.step.U_human)
    # The first hand maps onto the robot; from there the robot moves by the hand's motion.
    robot_move = records[-1].X_current.position - records[0].X_current.position
    np.testing.assert_allclose(robot_move, dp, atol=1e-9)


def test_the_first_fresh_tick_has_no_hand_motion_and_the_hand_maps_onto_the_robot() -> None:
    # The hand is far from the robot in the robot frame: the first sample is re-anchored.
    far = lambda t: state((0.1, 0.9, 0.1))  # noqa: E731
    loop = make_loop(far)
    r = run(loop, 0.2)[0]
    assert r.step is not None and r.hand is not None and r.hand.X_human is not None
    np.testing.assert_allclose(r.step.U_human, 0.0, atol=1e-12)
    np.testing.assert_allclose(r.hand.X_human.position, START.position, atol=1e-12)


def test_mode_and_parameter_changes_take_effect_at_the_next_tick_and_are_noted() -> None:
    loop = make_loop(moving((0.0, 0.0, -0.1)), Mode.DS)
    run(loop, 0.5)
    loop.controls.set_mode("S")
    loop.controls.set_params(kappa=8.0)
    r = run(loop, 0.2, t0=0.5)[0]
    assert r.mode is Mode.S and r.step is not None and np.ptp(r.step.alpha) == 0.0
    assert r.notes == ('params:{"kappa": 8.0}', "mode:S")
    assert loop.config.arbitration.kappa == 8.0
    loop.controls.set_params(kappa=-1.0)  # out of its domain: ignored, logged
    run(loop, 0.1, t0=0.7)
    assert loop.config.arbitration.kappa == 8.0


def test_a_segment_end_adds_an_attempt_and_restarts_the_start_states(tmp_path: Path) -> None:
    # The hand goes to the pick goal (the autonomous robot too), then stays.
    hand = ScriptedHand(lambda t: START)
    loop = TeleopLoop(
        LoopConfig(mode=Mode.AUTONOMOUS),
        hand,
        *fake_world(start=START),
        clock=ManualClock(0.0),
        history_file=HistoryFile(tmp_path / HISTORY_FILE),
    )
    records: list[TickRecord] = []
    while not records or records[-1].phase is Phase.PICK:
        records += run(loop, DT, t0=len(records) * DT)
    assert any(e.kind.value == "goal" for e in records[-1].plant.events)
    assert len(loop.history) == 1
    saved = OperatorHistory.from_dict(json.loads((tmp_path / HISTORY_FILE).read_text()))
    assert len(saved) == 1
    np.testing.assert_allclose(loop.state.X_start.position, records[-1].X_current.position)
    assert loop.state.X_start is not START  # restarted at the grasp
    run(loop, 4.0, t0=len(records) * DT)
    assert loop.outcome == "success"
    assert len(loop.history) == 2  # the place segment ends with the outcome


# --- stale input ------------------------------------------------------------------------


def test_hidden_hand_halts_the_robot_within_0_2_s_and_resumes_without_a_jump() -> None:
    hide_at, show_at = 1.5, 2.5
    v = np.array([0.0, -0.08, -0.04])  # m/s: the hand is moving when it disappears

    def path(t: float) -> HandState | None:
        if hide_at <= t < show_at:
            return None
        extra = np.array([0.0, 0.0, 0.05]) if t >= show_at else 0.0  # moved while lost
        return HandState(
            START.position + v * min(max(t - 0.3, 0.0), 2.0) + extra, START.rotation, np.ones(4)
        )

    loop = make_loop(path)
    records = run(loop, 3.5)
    t = np.array([r.t_s for r in records])
    last_fresh = max(
        r.hand.t_capture_s
        for r in records
        if r.hand and r.hand.X_human is not None and r.t_s < show_at
    )
    assert last_fresh == pytest.approx(hide_at - DT, abs=1e-6)
    speed = speeds(records)  # speed[k] between ticks k and k+1
    assert speed[(t[1:] > hide_at - 0.4) & (t[1:] < hide_at - 0.1)].min() > 0.05
    after = speed[(t[1:] >= last_fresh + 0.2) & (t[1:] < show_at)]
    assert after.max() < 1e-9, after  # stopped within 0.2 s of the last fresh sample
    lost = [r for r in records if hide_at + 0.01 < r.t_s < show_at]
    assert all(r.status is Status.LOST and r.reason == "no hand" and r.step is None for r in lost)
    # The command ramps down and is never a repeated stale one.
    cmds = [float(np.linalg.norm(r.U_cmd[:3])) for r in lost]
    assert cmds[-1] == 0.0 and all(b <= a for a, b in itertools.pairwise(cmds))
    # Back: the hand maps to where the command was; no jump beyond one tick at v_max.
    back = speed[(t[1:] >= show_at) & (t[1:] < show_at + 0.5)]
    assert back.max() <= loop.config.arbitration.v_max_mps * 1.0001
    first_back = next(r for r in records if r.t_s >= show_at and r.step is not None)
    assert first_back.step is not None
    np.testing.assert_allclose(first_back.step.U_human, 0.0, atol=1e-12)


def test_a_lost_robot_halts_the_loop_as_a_lost_hand_does_and_it_resumes() -> None:
    # The robot's state goes stale (a linked robot whose far end stopped publishing) from
    # 1.5 s to 2.5 s, while the hand keeps moving.
    loop = make_loop(moving((0.0, -0.10, -0.06), T=3.0))
    assert isinstance(loop.robot, FakeRobot)
    loop.robot.lost_between = (1.5, 2.5)
    records = run(loop, 3.5)
    t = np.array([r.t_s for r in records])
    speed = speeds(records)
    assert speed[(t[1:] > 1.0) & (t[1:] < 1.4)].min() > 0.01  # it was moving
    lost = [r for r in records if r.reason == ROBOT_LOST]
    assert loop.robot_lost_ticks == len(lost)
    assert lost and all(r.status is Status.LOST and r.step is None for r in lost)
    # lost once its newest state is older than 0.2 s (one tick to learn it)
    assert 1.5 + ROBOT_STALE_S - DT <= lost[0].t_s <= 1.5 + ROBOT_STALE_S + 2 * DT
    # the halt ramp: the command is zero within the ramp
    t_zero = lost[0].t_s + loop.config.halt_ramp_s + DT
    assert all(float(np.abs(r.U_cmd).max()) == 0.0 for r in lost if r.t_s >= t_zero)
    cmds = [float(np.linalg.norm(r.U_cmd[:3])) for r in lost]
    assert cmds[-1] == 0.0 and all(b <= a for a, b in itertools.pairwise(cmds))
    # back: tracking again, re-anchored (no jump beyond one tick at v_max)
    back = [r for r in records if r.t_s > lost[-1].t_s]
    assert back and back[-1].status is Status.TRACKING
    assert speed[t[1:] > lost[-1].t_s].max() <= loop.config.arbitration.v_max_mps * 1.0001
    first_back = next(r for r in back if r.step is not None)
    assert first_back.step is not None
    np.testing.assert_allclose(first_back.step.U_human, 0.0, atol=1e-12)


def _run_with_stop(
    loop: TeleopLoop, seconds: float, stop_at: float, resume_at: float
) -> list[TickRecord]:
    """`run`, pressing Stop just before the tick at `stop_at` and Resume before `resume_at`
    (as the page's buttons do: through the controls, taken at the next tick)."""
    out = []
    for k in range(round(seconds / DT)):
        t = k * DT
        if abs(t - stop_at) < DT / 2:
            loop.controls.stop_robot()
        if abs(t - resume_at) < DT / 2:
            loop.controls.resume_robot()
        loop.clock.sleep_until(t)
        out.append(loop.tick(t))
    return out


def test_a_latched_stop_halts_as_a_lost_hand_does_until_resume_and_is_recorded(
    tmp_path: Path,
) -> None:
    # The hand keeps moving and is tracked all along; the operator stops at 1.5 s and
    # resumes at 2.5 s.
    stop_at, resume_at = 1.5, 2.5
    loop = make_loop(moving((0.0, -0.10, -0.06), T=3.0))
    loop.start_recording(tmp_path / "s")
    records = _run_with_stop(loop, 3.5, stop_at, resume_at)
    loop.close()
    t = np.array([r.t_s for r in records])
    speed = speeds(records)
    assert speed[(t[1:] > 1.0) & (t[1:] < stop_at)].min() > 0.01  # it was moving
    stopped = [r for r in records if r.stopped]
    assert stopped[0].t_s == pytest.approx(stop_at) and stopped[-1].t_s < resume_at
    assert len(stopped) == round((resume_at - stop_at) / DT)
    # Latched: every tick until Resume halts, though the hand is fresh all the time.
    assert all(r.hand is not None and r.hand.X_human is not None for r in stopped)
    assert all(r.status is Status.LOST and r.reason == loop_tick.STOPPED for r in stopped)
    assert all(r.step is None for r in stopped)
    # The lost hand's halt: the command ramps down from the last one, never up, and is 0
    # once the ramp is over; the arm then stands still.
    cmds = [float(np.linalg.norm(r.U_cmd[:3])) for r in stopped]
    assert cmds[0] > 0.0 and all(b <= a for a, b in itertools.pairwise(cmds))
    t_zero = stop_at + loop.config.halt_ramp_s + DT
    assert all(float(np.abs(r.U_cmd).max()) == 0.0 for r in stopped if r.t_s >= t_zero)
    still = speed[(t[1:] > t_zero + DT) & (t[1:] < resume_at)]
    assert still.size > 20 and still.max() < 1e-9, still
    # Resume: tracking again, re-anchored (the hand moved on meanwhile: no jump).
    back = [r for r in records if r.t_s >= resume_at]
    assert not any(r.stopped for r in back) and back[-1].status is Status.TRACKING
    assert speed[t[1:] > resume_at].max() <= loop.config.arbitration.v_max_mps * 1.0001
    first_back = next(r for r in back if r.step is not None)
    assert first_back.step is not None
    np.testing.assert_allclose(first_back.step.U_human, 0.0, atol=1e-12)
    assert speed[t[1:] > resume_at + 0.3].max() > 0.01  # and the hand drives it again
    # The press and the resume are events of the tick they took effect in, in the record,
    # the loop's log and the recorded episode; the stopped flag reads back.
    assert [(round(r.t_s, 6), r.notes) for r in records if r.notes] == [
        (stop_at, ("stop",)),
        (resume_at, ("resume",)),
    ]
    assert [e for _, e in loop.events_log] == ["stop", "resume"] and loop.stops == 1
    session = read_session(tmp_path / "s")
    assert [r.stopped for r in session.records] == [r.stopped for r in records]
    (episode,) = session.episodes
    assert [e for _, e in episode.events] == ["stop", "resume"]
    assert [k for k, _ in episode.events] == [stopped[0].k, back[0].k]


def test_a_stop_halts_also_under_the_assist_policy_and_wins_over_a_resume_in_its_tick() -> None:
    loop = make_loop(lambda t: None if t > 0.5 else START, Mode.DS, LostPolicy.ASSIST)
    run(loop, 1.0)
    loop.controls.stop_robot()
    loop.controls.resume_robot()  # in the same tick: the stop stays
    loop.controls.stop_robot()  # a second press changes nothing
    records = run(loop, 1.0, t0=1.0)
    assert loop.stopped and loop.stops == 1
    assert all(r.stopped and r.status is Status.LOST and r.step is None for r in records)
    assert all(r.reason == loop_tick.STOPPED for r in records)
    assert float(np.abs(records[-1].U_cmd).max()) == 0.0
    assert speeds(records[5:]).max() < 1e-9  # no assist while stopped
    loop.controls.resume_robot()
    after = run(loop, 0.5, t0=2.0)
    assert not any(r.stopped for r in after) and after[0].notes == ("resume",)
    assert loop.stops == 1
    assert all(r.status is Status.ASSIST for r in after)  # the policy again


def test_nan_in_the_hand_data_counts_as_stale() -> None:
    def corrupt(inp: HumanInput) -> HumanInput:
        if inp.t_capture_s >= 1.0 and inp.X_human is not None:
            return HumanInput(inp.seq, inp.t_capture_s, inp.t_tracked_s, None, INVALID)
        return inp

    loop = make_loop(
        moving((0.0, -0.05, -0.05)), hand=ScriptedHand(moving((0.0, -0.05, -0.05)), corrupt=corrupt)
    )
    records = run(loop, 1.6)
    late = [r for r in records if r.t_s > 1.05]
    assert all(r.status is Status.LOST and r.reason == INVALID for r in late)
    assert speeds(records[-5:]).max() < 1e-9


def test_a_stalled_camera_is_detected_by_age() -> None:
    frozen: list[HumanInput] = []

    def corrupt(inp: HumanInput) -> HumanInput:
        if inp.t_capture_s < 1.0:  # then the same old sample keeps coming
            frozen[:] = [inp]
            return inp
        return frozen[0]

    path = moving((0.0, -0.05, -0.05))
    loop = make_loop(path, hand=ScriptedHand(path, corrupt=corrupt))
    records = run(loop, 1.6)
    last = frozen[0].t_capture_s
    for r in records:
        if r.t_s > last + 0.1 + 1e-6:
            assert r.status is Status.LOST and r.reason == loop_tick.STALLED
        else:
            assert r.status is Status.TRACKING


def test_halt_policy_does_not_move_without_a_hand() -> None:
    loop = make_loop(lambda t: None, Mode.DS)
    records = run(loop, 1.0)
    assert all(r.status is Status.LOST and r.reason == "no hand" for r in records)
    assert speeds(records).max() == 0.0
    assert float(np.linalg.norm(records[-1].U_cmd)) == 0.0


def test_assist_policy_keeps_going_towards_the_goal_at_reduced_speed() -> None:
    loop = make_loop(lambda t: None if t > 0.5 else START, Mode.DS, LostPolicy.ASSIST)
    records = run(loop, 3.0)
    assisting = [r for r in records if r.t_s > 0.6]
    assert all(r.status is Status.ASSIST for r in assisting)
    goal = loop.task.goal()
    assert goal is not None
    d = [float(np.linalg.norm(r.X_current.position - goal.position)) for r in assisting]
    assert d[-1] < d[0] - 0.05
    for r in assisting[:20]:
        assert r.step is not None
        np.testing.assert_allclose(r.U_cmd, r.step.U_robot * loop.config.assist_speed)
    top = max(float(np.linalg.norm(r.U_cmd[:3])) for r in assisting)
    assert top <= loop.config.arbitration.v_max_mps * loop.config.assist_speed + 1e-9


def test_an_injected_input_delay_delays_the_robot() -> None:
    path = moving((0.0, -0.1, 0.0), t0=0.5, T=1.5)
    runs = {}
    for delay in (0.0, 0.2):
        loop = make_loop(path, input_delay_s=delay)
        runs[delay] = run(loop, 3.0)
        assert loop.session_meta()["loop"]["input_delay_s"] == delay

    def t_half(records: list[TickRecord]) -> float:
        y = np.array([r.X_current.position[1] for r in records])
        return float(records[int(np.argmax(np.abs(y - y[0]) >= 0.5 * abs(y[-1] - y[0])))].t_s)

    assert t_half(runs[0.2]) - t_half(runs[0.0]) == pytest.approx(0.2, abs=DT + 1e-6)


# --- observers --------------------------------------------------------------------------


def test_a_slow_observer_only_misses_records() -> None:
    loop = make_loop(moving((0.0, -0.05, 0.0)), Mode.DS)
    stalled = loop.broadcaster.subscribe()  # never reads
    reader = loop.broadcaster.subscribe()
    seen = []
    for k in range(60):
        loop.clock.sleep_until(k * DT)
        loop.tick(k * DT)
        if k % 10 == 9:
            r = reader.latest()
            assert r is not None
            seen.append(r.k)
    assert stalled.received == 60 and stalled.dropped == 59
    newest = stalled.latest()
    assert newest is not None and newest.k == 59  # newest wins, one slot
    assert seen == [9, 19, 29, 39, 49, 59]


def test_observers_get_every_record_in_order() -> None:
    seen: list[int] = []

    class Eyes:
        def observe(self, record: TickRecord) -> None:
            seen.append(record.k)

    loop = TeleopLoop(
        LoopConfig(),
        ScriptedHand(lambda t: START),
        *fake_world(start=START),
        ManualClock(0.0),
        observers=(Eyes(),),
    )
    run(loop, 1.0)
    assert seen == list(range(30))


# --- recording --------------------------------------------------------------------------


def test_a_recording_starts_with_the_task_and_closes_complete(tmp_path: Path) -> None:
    loop = make_loop(moving((0.0, -0.05, 0.0)), Mode.DS)
    run(loop, 0.5)
    assert isinstance(loop.robot, FakeRobot)
    resets = loop.robot.resets
    folder = tmp_path / "s"
    loop.start_recording(folder, {"command": "test"})  # the loop has ticked: the task resets
    assert loop.tick_index == 0 and loop.robot.resets == resets + 1
    run(loop, 1.0, t0=0.5)
    loop.close()
    s = read_session(folder)
    assert s.complete and len(s.records) == 30 and s.meta["command"] == "test"
    assert s.records[0].X_reset is not None and all(r.X_reset is None for r in s.records[1:])
    np.testing.assert_allclose(s.records[0].X_reset.position, START.position)
    assert s.meta["mode"] == "DS" and s.meta["loop"]["arbitration"]["max_lead_m"] == 0.03
    assert isinstance(loop.hand, ScriptedHand) and loop.hand.closed


def test_a_recording_requested_through_the_controls_goes_under_the_record_root(
    tmp_path: Path,
) -> None:
    loop = TeleopLoop(
        LoopConfig(),
        ScriptedHand(lambda t: START),
        *fake_world(start=START),
        ManualClock(0.0),
        record_root=tmp_path,
    )
    loop.controls.set_recording(True)
    run(loop, 0.3)
    recording = loop.recording
    assert recording is not None and recording.parent == tmp_path
    assert recording.name.endswith("-DS-thing")
    loop.controls.set_recording(False)
    run(loop, 0.1, t0=0.3)
    assert tmp_path.joinpath(recording.name, "ticks.jsonl").stat().st_size > 0
    assert loop.recording is None  # closed by the request
    (folder,) = tmp_path.iterdir()
    assert read_session(folder).complete


# --- the pure tick ----------------------------------------------------------------------


def test_decide_and_absorb_are_pure() -> None:
    from dsteleop.arbitration import make_arbiter

    cfg = LoopConfig(mode=Mode.DS)
    arbiter = make_arbiter(cfg.mode, cfg.arbitration)
    s0 = loop_tick.start(START, arbiter, OperatorHistory())
    inp = HumanInput(0, 0.0, 0.0, START)
    s1, d = loop_tick.decide(s0, cfg, arbiter, inp, state((0.5, 0.1, 0.2)), 0.0, None)
    assert d.status is Status.TRACKING and d.step is not None
    assert s0.lost and s0.X_human_last is None  # the old state is untouched
    assert not s1.lost and s1.X_ref is d.X_next
    s2, d2 = loop_tick.decide(s1, cfg, arbiter, None, state((0.5, 0.1, 0.2)), DT, None)
    assert d2.status is Status.LOST and d2.reason == loop_tick.NO_INPUT and s2.lost
    s3, ended = loop_tick.absorb(s2, dataclasses.replace(_step(d2.X_next), events=()), arbiter)
    assert not ended and s3.X_prev is s2.X_current


def _step(X: HandState):
    from dsteleop.app.ports import PlantStep

    return PlantStep(X, Phase.PICK)


def test_the_loop_logic_runs_without_pybullet_zenoh_or_a_camera() -> None:
    code = (
        "import sys\n"
        "from tests import test_loop as t\n"
        "t.test_manual_mode_moves_the_robot_exactly_as_the_hand_moves()\n"
        "t.test_hidden_hand_halts_the_robot_within_0_2_s_and_resumes_without_a_jump()\n"
        "t.test_a_lost_robot_halts_the_loop_as_a_lost_hand_does_and_it_resumes()\n"
        "heavy = ('pybullet', 'cv2', 'mediapipe', 'viser', 'zenoh', 'rosbags')\n"
        "heavy = [m for m in heavy if m in sys.modules]\n"
        "print(heavy)\n"
        "assert not heavy, heavy\n"
    )
    repo = Path(__file__).resolve().parents[1]
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def _lowered_threads_after_a_real_time_run() -> tuple[int, int, int]:
    """(loop thread's niceness, a worker thread's niceness after two real-time ticks, the
    worker's after a second run): in a subprocess, so that the test process keeps its own."""
    import os
    import threading

    from dsteleop.app.loop.timing import MonotonicClock

    release = threading.Event()
    ids: list[int] = []

    def wait() -> None:
        ids.append(threading.get_native_id())
        release.wait(30)

    worker = threading.Thread(target=wait)
    worker.start()
    while not ids:
        pass
    loop = TeleopLoop(LoopConfig(mode=Mode.MANUAL), ScriptedHand(lambda t: START),
                      *fake_world(start=START), clock=MonotonicClock())  # fmt: skip
    loop.run(max_ticks=2)
    after_one = os.getpriority(os.PRIO_PROCESS, ids[0])
    loop.run(max_ticks=2)
    after_two = os.getpriority(os.PRIO_PROCESS, ids[0])
    release.set()
    worker.join()
    loop.close()
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id()), after_one, after_two


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="per-thread niceness: Linux")
def test_a_real_time_run_puts_every_other_thread_below_the_loop() -> None:
    code = "from tests import test_loop as t\nprint(*t._lowered_threads_after_a_real_time_run())\n"
    repo = Path(__file__).resolve().parents[1]
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    loop_nice, after_one, after_two = map(int, r.stdout.split())
    assert after_one == loop_nice + 5  # below the loop by LOOP_LEAD_NICENESS
    assert after_two == after_one  # a second run does not push it further down
