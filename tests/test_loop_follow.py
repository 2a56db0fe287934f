"""The loop's tick follows the camera (`timing.RateClock`, frame-following schedule).

Most tests run the real loop (`TeleopLoop.wait_for_tick` + `tick`, as `run` does) on a manual
clock with `FramedHand`, whose frames become ready at controlled times: deterministic, and
exact to the microsecond. Two tests use the real clock with a live tracking stream; they
assert orderings and counts that load cannot break (load only delays and thins ticks).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.inputs.recorded import RecordedHandInput
from dsteleop.app.inputs.tracked import TrackedHandInput
from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.loop import tick as loop_tick
from dsteleop.app.loop.timing import (
    FOLLOW_DRIFT,
    FOLLOW_EARLY,
    FOLLOW_LATE,
    ManualClock,
    MonotonicClock,
    TickTiming,
)
from dsteleop.app.session.schema import Status, TickRecord
from dsteleop.arbitration import HandState, Mode
from dsteleop.tracking.mapping import WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import VideoFileSource
from dsteleop.tracking.synthetic import SyntheticSource, scripted_trajectory
from tests.deadlines import HUNG_S

from .fakes import DT, FramedHand, ScriptedHand, fake_world, state

START = state((0.5, 0.3, 0.4))
P = DT  # the loop's period at 30 Hz


def still(t: float) -> HandState:
    return START


def moving(t: float) -> HandState:
    v = np.array([0.0, -0.08, -0.04])  # m/s: moving when the camera stalls
    return HandState(START.position + v * min(t, 3.0), START.rotation, np.ones(4))


def tracking_times(seed: int = 0, spikes: bool = True) -> list[float]:
    """Tracker times per frame [s]: 20 ms +- 4 ms, and 2 % of frames 25 ms slower."""
    rng = np.random.default_rng(seed)
    t = rng.normal(0.020, 0.004, 10000).clip(0.008, 0.06)
    if spikes:
        t[rng.random(10000) < 0.02] += 0.025
    return [float(x) for x in t]


def run_following(
    hand: ScriptedHand, seconds: float, follow: bool = True, path=still
) -> tuple[list[TickTiming], list[TickRecord]]:
    loop = TeleopLoop(
        LoopConfig(mode=Mode.MANUAL), hand, *fake_world(start=START), clock=hand_clock(hand),
        follow_frames=follow,
    )  # fmt: skip
    timings, records = [], []
    while loop.clock.now() < seconds:
        timing = loop.wait_for_tick()
        timings.append(timing)
        records.append(loop.tick(timing.t_start_s, timing.jitter_s))
    return timings, records


def hand_clock(hand: ScriptedHand) -> ManualClock:
    clock = getattr(hand, "clock", None)
    return clock if isinstance(clock, ManualClock) else ManualClock(0.0)


def frame_lags_s(records: list[TickRecord], after_s: float) -> NDArray[np.float64]:
    """For each frame the loop used: its tick's start minus when the frame was ready."""
    seen: set[int] = set()
    lags = []
    for r in records:
        if r.hand is not None and r.hand.seq not in seen and r.t_s >= after_s:
            seen.add(r.hand.seq)
            lags.append(r.t_s - r.hand.t_tracked_s)
    return np.asarray(lags)


def test_a_tick_starts_when_its_frame_is_ready_not_up_to_a_period_later() -> None:
    trk = tracking_times()
    for fps in (30.0, 29.7757):  # a webcam's rate, and the test video's
        clock = ManualClock(0.0)
        hand = FramedHand(still, clock, fps=fps, tracking_s=trk.__getitem__, duration_s=21.0)
        timings, records = run_following(hand, 20.0)
        starts = np.array([t.t_start_s for t in timings])
        assert np.diff(starts).min() >= (1 - FOLLOW_EARLY) * P - 1e-9  # never sooner
        # A tick that starts on a frame starts when it is ready, or when the tick's window
        # opens if it was ready before (never before the frame).
        for t, r in zip(timings, records, strict=True):
            if t.on_frame:
                assert r.hand is not None and t.t_start_s >= r.hand.t_tracked_s - 1e-12
        lag = frame_lags_s(records, after_s=1.0)
        assert np.median(lag) < 0.001, fps  # most frames start their tick at once
        assert np.mean([t.on_frame for t in timings]) > 0.9
        assert len(lag) >= 0.9 * fps * 19  # nearly every frame drives a tick
        # The same frames on the fixed schedule wait for the free-running clock.
        clock = ManualClock(0.0)
        hand = FramedHand(still, clock, fps=fps, tracking_s=trk.__getitem__, duration_s=21.0)
        _, fixed = run_following(hand, 20.0, follow=False)
        assert np.median(frame_lags_s(fixed, after_s=1.0)) > 0.005


def test_a_60_fps_camera_does_not_make_a_60_hz_loop() -> None:
    trk = [t / 2 for t in tracking_times()]  # 10 ms a frame: the tracker keeps up
    clock = ManualClock(0.0)
    hand = FramedHand(still, clock, fps=60.0, tracking_s=trk.__getitem__, duration_s=21.0)
    timings, _ = run_following(hand, 20.0)
    starts = np.array([t.t_start_s for t in timings])
    rate_hz = (len(starts) - 1) / (starts[-1] - starts[0])
    assert 30.0 * 0.99 <= rate_hz <= 30.0 * (1 + FOLLOW_DRIFT) * 1.001
    assert np.diff(starts).min() >= (1 - FOLLOW_EARLY) * P - 1e-9
    assert all(t.on_frame for t in timings[1:])  # a new frame every tick


def test_a_slow_camera_keeps_the_loop_at_its_rate() -> None:
    for fps in (15.0, 10.0):  # a webcam in low light
        clock = ManualClock(0.0)
        trk = tracking_times(spikes=False)
        hand = FramedHand(still, clock, fps=fps, tracking_s=trk.__getitem__, duration_s=21.0)
        timings, _ = run_following(hand, 20.0)
        starts = np.array([t.t_start_s for t in timings])
        rate_hz = (len(starts) - 1) / (starts[-1] - starts[0])
        assert 30.0 * 0.99 <= rate_hz <= 30.0 * (1 + FOLLOW_DRIFT) * 1.001, fps


def test_a_stalled_camera_ticks_at_the_rate_and_halts_the_robot_on_time() -> None:
    stall_at = 2.0
    clock = ManualClock(0.0)
    trk = tracking_times(spikes=False)
    hand = FramedHand(moving, clock, tracking_s=trk.__getitem__, stall_at_s=stall_at)
    timings, records = run_following(hand, 3.5)
    t = np.array([r.t_s for r in records])
    last = max(r.hand.t_capture_s for r in records if r.hand is not None)
    stale_at = last + LoopConfig().stale_limit_s
    assert last == pytest.approx(stall_at - P, abs=1e-6)
    # While frames come, ticks follow them; the first tick without one waits at most
    # FOLLOW_LATE past its period, then the ticks come every period.
    gaps = np.diff(t)
    after = t[1:] > stale_at
    assert gaps.max() <= (1 + FOLLOW_LATE) * P + 1e-9
    np.testing.assert_allclose(gaps[after], P, atol=1e-9)
    assert all(not tm.on_frame for tm, r in zip(timings, records, strict=True) if r.t_s > last + P)
    # The halt: first stale tick within a period of the stale time, the command ramps to 0,
    # the arm stands still within 0.2 s of the last fresh sample (as on the fixed schedule).
    first_stale = next(r for r in records if r.status is Status.LOST and r.t_s > last)
    assert first_stale.reason == loop_tick.STALLED
    assert stale_at < first_stale.t_s <= stale_at + P + 1e-9
    p = np.array([r.X_current.position for r in records])
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / P
    assert speed[(t[1:] > last - 0.3) & (t[1:] < last - 0.05)].min() > 0.05  # it was moving
    assert speed[t[1:] >= last + 0.2].max() < 1e-9


def test_a_tick_never_waits_for_a_frame_past_the_moment_its_input_goes_stale() -> None:
    # A camera that keeps pace: the tick after its last frame waits FOLLOW_LATE for one
    # more (it is due) ...
    clock = ManualClock(0.0)
    hand = FramedHand(moving, clock, tracking_s=lambda k: 0.02, stall_at_s=2.0)
    timings, records = run_following(hand, 3.0)
    last = next(k for k, r in enumerate(records) if r.hand is not None and r.hand.seq == 59)
    waited = timings[last + 1].t_start_s - timings[last].t_start_s
    assert waited == pytest.approx((1 + FOLLOW_LATE) * P, abs=1e-9)
    # ... but a tracker 90 ms slow brings each frame 10 ms before it goes stale: the tick
    # after the last frame does not wait past that (it starts one period after the last).
    clock = ManualClock(0.0)
    hand = FramedHand(moving, clock, tracking_s=lambda k: 0.09, stall_at_s=2.0)
    timings, records = run_following(hand, 3.0)
    last = next(k for k, r in enumerate(records) if r.hand is not None and r.hand.seq == 59)
    assert timings[last].on_frame
    waited = timings[last + 1].t_start_s - timings[last].t_start_s
    assert waited == pytest.approx(P, abs=1e-9)


def test_sources_without_frames_keep_the_fixed_schedule() -> None:
    # A scripted hand (no frames of its own): the schedule is the fixed one, tick k at k P.
    timings, _ = run_following(ScriptedHand(still), 5.0)
    starts = np.array([t.t_start_s for t in timings])
    np.testing.assert_allclose(starts, np.arange(len(starts)) * P, atol=1e-9)
    assert all(t.jitter_s == 0.0 and not t.on_frame and not t.overrun for t in timings)
    # A hand with frames, told not to follow them: the same fixed schedule.
    clock = ManualClock(0.0)
    timings, _ = run_following(FramedHand(still, clock), 5.0, follow=False)
    starts = np.array([t.t_start_s for t in timings])
    np.testing.assert_allclose(starts, np.arange(len(starts)) * P, atol=1e-9)
    # The demo's synthetic hand (no pixels) and a recording are paced by the loop; a video
    # (or a camera) through a live stream has arrivals.
    demo = TrackingStream(SyntheticSource(scripted_trajectory(), realtime=True), HandTracker())
    assert TrackedHandInput.from_stream(demo, WorkspaceMapping()).arrivals is None
    assert RecordedHandInput([]).arrivals is None
    video = TrackingStream(VideoFileSource(Path("any.mp4"), realtime=True), HandTracker())
    assert TrackedHandInput.from_stream(video, WorkspaceMapping()).arrivals is not None


def live_loop(fps: float) -> tuple[TeleopLoop, TrackingStream]:
    source = SyntheticSource(scripted_trajectory(), fps=fps, realtime=True)
    stream = TrackingStream(source, HandTracker())
    hand = TrackedHandInput.from_stream(stream.open(), WorkspaceMapping(), follow=True)
    cfg = LoopConfig(mode=Mode.MANUAL)
    return TeleopLoop(cfg, hand, *fake_world(start=START), clock=MonotonicClock()), stream


def test_on_the_real_clock_ticks_follow_the_frames_of_a_live_stream() -> None:
    loop, stream = live_loop(30.0)
    try:
        loop.hand.start()
        assert stream.wait_for(0, 5.0) is not None
        timings, records = [], []
        for _ in range(90):
            timing = loop.wait_for_tick()
            timings.append(timing)
            records.append(loop.tick(timing.t_start_s, timing.jitter_s))
    finally:
        loop.close()
    # No tick was due sooner than the window allows after the previous one was due (a late
    # wake-up can only make a tick start later than it was due).
    due = np.array([t.t_due_s for t in timings])
    assert np.diff(due).min() >= (1 - FOLLOW_EARLY) * P - 1e-9
    assert all(t.t_start_s >= t.t_due_s for t in timings)
    for t, r in zip(timings, records, strict=True):
        assert r.hand is not None
        # A tick that started on a frame started after that frame was tracked, and used it
        # (or a newer one).
        if t.on_frame:
            assert t.t_start_s >= r.hand.t_tracked_s
    assert np.mean([t.on_frame for t in timings]) > 0.5  # generous: a loaded machine


def test_on_the_real_clock_a_60_fps_stream_does_not_make_a_60_hz_loop() -> None:
    loop, stream = live_loop(60.0)
    try:
        loop.hand.start()
        assert stream.wait_for(0, 5.0) is not None
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 2.0:
            timing = loop.wait_for_tick()
            loop.tick(timing.t_start_s, timing.jitter_s)
            n += 1
    finally:
        loop.close()
    # Load can only thin the ticks; the schedule allows at most about 30 Hz (+1 tick at the
    # edges of the window, +1 % drift).
    assert n <= math.ceil(2.0 * 30.0 * (1 + FOLLOW_DRIFT)) + 2
    assert n >= 10


def test_a_delayed_input_is_ready_once_it_is_the_delay_old() -> None:
    # With an injected input delay a frame drives the loop only once it is that old: the
    # arrivals say it is ready then, not when it was tracked.
    delay_s = 0.1
    source = SyntheticSource(scripted_trajectory(), fps=30.0, realtime=True)
    stream = TrackingStream(source, HandTracker())
    hand = TrackedHandInput.from_stream(stream.open(), WorkspaceMapping(), delay_s, follow=True)
    arrivals = hand.arrivals
    assert arrivals is not None
    try:
        hand.start()
        for _ in range(5):
            ready = arrivals.wait_newer(time.monotonic() + HUNG_S)
            now = time.monotonic()
            assert ready is not None and ready <= now
            inp = hand.poll(now)
            assert inp is not None
            assert ready >= inp.t_capture_s + delay_s - 1e-9  # not before it is the delay old
            assert now - inp.t_capture_s >= delay_s
        # Nothing new right after a poll, until a frame arrives (or the time is up).
        assert arrivals.wait_newer(time.monotonic()) is None
    finally:
        hand.close()
