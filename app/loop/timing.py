"""One object owns the loop's timing: a rate clock that measures itself.

`RateClock` schedules tick k at `t0 + k * period` on a monotonic clock. After a late tick it
re-anchors (the next deadline is one period after the late start) instead of bursting to catch
up, and counts the overrun. Every tick records its start-time jitter (actual start minus
scheduled start) and its duration; `summary()` gives medians and tail percentiles, and the
share of the last `OVERRUN_WINDOW_S` seconds of ticks that overran: at `SUSTAINED_OVERRUN`
or more the loop does not keep its rate (`sustained_overrun`), which the run's summary, the
log and the browser view's status say. A headless run (no schedule: as fast as the machine
allows) counts its ticks and their durations through `count`.

With a hand that has frames of its own (a camera, a video played live: `ports.InputArrivals`)
the tick follows the camera instead (`wait(arrivals, latest_s)`), so that a fresh frame does
not wait for a free-running clock. Let P be the period and s the moment the previous tick was
due (its frame's arrival, its window's opening or its deadline; re-anchored after an overrun,
as on the fixed schedule, so that the thread's wake-up delays do not add up):

- the tick starts as soon as a new tracked frame is ready, but not before its window opens at
  s + P - FOLLOW_EARLY P (at once then, when a new frame was already waiting); after a tick
  that started without a new frame, the window opens at s + P (the frame that tick missed is
  not worth an early tick: it would add a tick the camera did not pace);
- with no new frame it starts at its deadline: s + P, or s + P + FOLLOW_LATE P when the last
  tick started on a new frame and the camera keeps pace with the loop (frames at most
  FOLLOW_SLOWER P slower than the ticks) and has its next frame due by then (a frame a little
  late; not a tracker that cannot keep up), never past `latest_s`, when the loop's
  input goes stale (so a stalled camera halts the robot when it would on the fixed
  schedule: once a frame is overdue the ticks come every P, docs/ARCHITECTURE.md);
- the loop's world (P per tick) never runs ahead of the wall clock by more than FOLLOW_AHEAD P:
  early ticks add to how far it is ahead, late ones take from it; being behind by more than
  FOLLOW_BEHIND P is forgiven (a camera slower than the rate), and being ahead by
  FOLLOW_DRIFT P a tick, so the loop keeps pace with a camera up to 1 % faster than its rate
  and a faster camera (60 fps) gives at most 1 % more ticks than the rate.

Ticks are due at least (1 - FOLLOW_EARLY) P apart (a thread that wakes late can only start a
tick later than it was due, as on the fixed schedule). A tick that follows a frame starts
right after it (the tracker's time per frame plus the loop's wake-up); the schedule locks
onto a camera of about the loop's rate (from FOLLOW_SLOWER slower to 1 % faster) and then
runs at its pace; with a camera of another rate (15, 25 or 60 fps) the ticks keep about the
loop's rate and start on a new frame when one is ready in their window. A strict "never
sooner than P after the previous tick" cannot stay locked onto a camera of exactly the
loop's rate: one late frame delays its tick, and every later frame then waits for the
period, so the lag grows to the largest delay ever seen; the early margin lets the schedule
come back.

Jitter is then the start minus the moment the schedule meant the tick to start (the frame's
arrival or the window's opening, or the deadline): how late the loop's thread woke, as on the
fixed schedule; an overrun is a tick that started more than a period after that moment, and
`on_frame_share` in the summary the share of ticks that started on a new frame.

`ports.Clock` is the seam tests use to inject time: `MonotonicClock` is the real one; `ManualClock`
advances only when told to.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from dsteleop.app.ports import Clock, InputArrivals
from dsteleop.errors import ConfigError

log = logging.getLogger(__name__)


def raise_priority(niceness: int = -10) -> bool:
    """Ask the OS to schedule this process ahead of ordinary work (a browser rendering on the
    same cores, a build). Threads started afterwards inherit it.

    Linux with autogroup scheduling (`kernel.sched_autogroup_enabled = 1`) first shares the
    CPU between sessions, so a process's niceness only counts inside its own session: a
    local browser (its own session) then takes half the CPU whatever our niceness. When this
    process leads its own session (started with `setsid`), the session's autogroup is ours
    alone and gets the same niceness; otherwise it is left as it is (it would raise every
    process of the user's terminal). Both need root or CAP_SYS_NICE; without them nothing
    changes and False is returned.
    """
    try:
        current = os.nice(0)
        if current > niceness:
            os.nice(niceness - current)
    except (OSError, AttributeError):
        log.info("could not raise the process priority (needs CAP_SYS_NICE); running as is")
        return False
    autogroup = "/proc/self/autogroup"
    if os.path.exists(autogroup) and os.getsid(0) == os.getpid():
        try:
            with open(autogroup, "w") as f:
                f.write(str(niceness))
        except OSError:
            log.info("could not raise the session's autogroup priority")
    return True


#: How far below the loop thread every other thread of the process runs (niceness steps).
LOOP_LEAD_NICENESS = 5


def put_this_thread_first(lead: int = LOOP_LEAD_NICENESS) -> int:
    """Make every other thread of this process at least `lead` niceness steps less urgent
    than the calling thread (the loop's). Returns how many threads were lowered.

    The loop shares the cores with its own capture, tracking (MediaPipe's threads among
    them), viewer and recorder threads, all at the process's niceness: a tick that falls due
    while they run waits for the scheduler to get round to it. Measured on a 2-core Xeon
    with MediaPipe on a real video, 60 s runs alternating with and without, 7 of each:
    start jitter p99 median 3.9 ms (2.1-13.6) against 13.8 ms (7.3-15.0), frame-to-command
    latency p50 33 against 40 ms, overruns 0 against 3 (`dsteleop bench --only loop`).
    Linux only (niceness is per thread there; /proc/self/task lists the threads); lowering a
    thread needs no privilege. Idempotent: a thread already that low is left as it is; a
    thread started later inherits its creator's niceness.
    """
    tasks = "/proc/self/task"
    if not os.path.isdir(tasks):
        return 0
    me = threading.get_native_id()
    target = os.getpriority(os.PRIO_PROCESS, me) + lead
    lowered = 0
    for name in os.listdir(tasks):
        tid = int(name)
        if tid == me:
            continue
        try:
            if os.getpriority(os.PRIO_PROCESS, tid) < target:
                os.setpriority(os.PRIO_PROCESS, tid, target)
                lowered += 1
        except OSError:  # the thread ended meanwhile, or the OS refused
            continue
    return lowered


class MonotonicClock:
    """`time.monotonic()`; sleeps with `time.sleep`, then spins the last 0.5 ms."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t_s: float) -> None:
        while True:
            remaining = t_s - time.monotonic()
            if remaining <= 0:
                return
            if remaining > 0.0015:
                time.sleep(remaining - 0.001)
            elif remaining > 0.0005:
                time.sleep(0)


class ManualClock:
    """A clock for tests and headless replay: time moves only by `advance` or `sleep_until`."""

    def __init__(self, t0_s: float = 0.0) -> None:
        self._t = t0_s
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, dt_s: float) -> None:
        with self._lock:
            self._t += dt_s

    def sleep_until(self, t_s: float) -> None:
        with self._lock:
            self._t = max(self._t, t_s)


@dataclass(frozen=True)
class TickTiming:
    """Timing of one tick [s]: when it was due, when it started, how late it started, and
    whether it started on a new frame (a schedule that follows the camera)."""

    index: int
    t_due_s: float
    t_start_s: float
    jitter_s: float
    overrun: bool
    on_frame: bool = False


#: The window over which the overrun share is measured [s].
OVERRUN_WINDOW_S = 10.0
#: An overrun share over the window at least this large is sustained: the rate is not kept.
SUSTAINED_OVERRUN = 0.1
#: Following the camera, a tick starts at the earliest this many periods before one period
#: after the previous tick, when a new frame is ready then ...
FOLLOW_EARLY = 0.1
#: ... and waits for a new frame at most this many periods past one period after it (its
#: deadline), when the camera keeps pace and its next frame is due by then ...
FOLLOW_LATE = 0.25
#: ... which is when its frames come at most this many periods slower than the loop's: the
#: loop slows down to follow a camera at most this much slower than its rate.
FOLLOW_SLOWER = 0.05
#: The loop's world never runs ahead of the wall clock by more than this many periods
#: (early ticks count ahead, late ones behind) ...
FOLLOW_AHEAD = 0.5
#: ... behind by more than this it is forgiven (a camera slower than the rate, a stall: the
#: loop does not burst to catch up) ...
FOLLOW_BEHIND = 10.0
#: ... and an ahead is forgiven by this many periods a tick: the loop keeps pace with a camera
#: up to 1 % faster than its rate, and a faster camera gives at most 1 % more ticks.
FOLLOW_DRIFT = 0.01


class RateClock:
    """Fixed-rate or frame-following scheduling with re-anchoring after overruns, and its own
    statistics (module docstring).

    Args:
        rate_hz: ticks per second.
        clock: time source (monotonic by default).
        history: how many recent ticks the statistics cover.
        follow_early, follow_late: the frame-following window around a tick's nominal time
            [periods] (`FOLLOW_EARLY`, `FOLLOW_LATE`).
    """

    def __init__(
        self,
        rate_hz: float,
        clock: Clock | None = None,
        history: int = 1800,
        follow_early: float = FOLLOW_EARLY,
        follow_late: float = FOLLOW_LATE,
    ) -> None:
        if not rate_hz > 0:
            raise ConfigError(f"rate_hz must be > 0, got {rate_hz}")
        for name, v in (("follow_early", follow_early), ("follow_late", follow_late)):
            if not 0 <= v < 0.5:
                raise ConfigError(f"{name} must be in [0, 0.5) periods, got {v}")
        self.period_s = 1.0 / rate_hz
        self.early_s = follow_early * self.period_s
        self.late_s = follow_late * self.period_s
        self.clock = clock or MonotonicClock()
        self._next_s: float | None = None
        self._index = 0
        self.overruns = 0
        self.frame_ticks = 0
        self._jitter = deque[float](maxlen=history)
        self._duration = deque[float](maxlen=history)
        self._late = deque[bool](maxlen=max(1, round(OVERRUN_WINDOW_S * rate_hz)))
        self._last_start: float | None = None
        self._ahead_s = 0.0  # following: how far the loop's world is ahead of the wall clock
        self._ready = deque[float](maxlen=8)  # following: when the frames of ticks were ready
        self._last_on_frame = True  # following: the last tick started on a new frame
        self.headless = False

    def wait(
        self, arrivals: InputArrivals | None = None, latest_s: float = -math.inf
    ) -> TickTiming:
        """Sleep until the next tick is due (fixed rate), or, given `arrivals`, until it
        follows a new frame (module docstring); return its timing.

        Args:
            arrivals: when new input is ready (None: the fixed schedule).
            latest_s: the latest a tick may wait for a frame past one period after the
                previous tick (when the loop's input goes stale) [s]; -inf: not past it.
        """
        now = self.clock.now()
        if self._next_s is None:
            self._next_s = now
        on_frame = False
        if arrivals is None:
            due = self._next_s
            if now < due:
                self.clock.sleep_until(due)
        else:
            due, ready = self._follow(arrivals, now, latest_s)
            on_frame = ready is not None
            if ready is not None and (not self._ready or ready > self._ready[-1]):
                self._ready.append(ready)
        now = self.clock.now()
        jitter = now - due
        overrun = jitter > self.period_s
        if overrun:
            # Late by more than a period: re-anchor on now instead of bursting to catch up.
            self.overruns += 1
            due = now
        self._next_s = due + self.period_s
        if arrivals is not None and self._last_start is not None:
            self._ahead_s = self._ahead(now - self._last_start)
        self.frame_ticks += on_frame
        self._last_on_frame = on_frame
        self._jitter.append(jitter)
        self._late.append(overrun)
        timing = TickTiming(self._index, now - jitter, now, jitter, overrun, on_frame)
        self._index += 1
        self._last_start = now
        return timing

    def _follow(
        self, arrivals: InputArrivals, now: float, latest_s: float
    ) -> tuple[float, float | None]:
        """When the next tick of the frame-following schedule is meant to start, and when
        the new frame it starts on was ready (None: none); sleeps and waits up to then."""
        if self._last_start is None:  # the first tick starts now
            return now, arrivals.wait_newer(now)
        P = self.period_s
        assert self._next_s is not None
        nominal = self._next_s  # one period after the last tick was due (or re-anchored)
        opens = max(nominal - self.early_s, nominal + self._ahead_s - FOLLOW_AHEAD * P)
        if not self._last_on_frame:
            opens = nominal  # the frame the last tick missed is not worth an early tick
        late = self.late_s if self._last_on_frame and self._frame_due_by(nominal) else 0.0
        deadline = max(opens, min(nominal + late, max(nominal, latest_s)))
        if now < opens:
            self.clock.sleep_until(opens)
        ready = arrivals.wait_newer(deadline)  # at once when a new frame is already waiting
        if ready is None:
            return deadline, None
        return max(ready, opens), ready

    def _frame_due_by(self, nominal_s: float) -> bool:
        """The camera keeps pace with the loop (its frames, as the recent ticks took them,
        come at most FOLLOW_SLOWER of a period slower) and its next frame is due within
        half a period before `nominal_s` and FOLLOW_LATE after it."""
        if len(self._ready) < 3:
            return False
        gaps = np.diff(np.asarray(self._ready))
        interval = float(gaps[gaps < 1.5 * np.median(gaps)].mean())  # a skipped frame aside
        if interval > (1 + FOLLOW_SLOWER) * self.period_s:
            return False
        expected = self._ready[-1] + interval
        return nominal_s - self.period_s / 2 <= expected <= nominal_s + self.late_s

    def _ahead(self, gap_s: float) -> float:
        """How far the world is ahead of the wall clock after a tick `gap_s` after the
        previous one [s]: behind is forgiven beyond `FOLLOW_BEHIND`, ahead at `FOLLOW_DRIFT`
        a tick."""
        P = self.period_s
        ahead = max(self._ahead_s + P - gap_s, -FOLLOW_BEHIND * P)
        return max(0.0, ahead - FOLLOW_DRIFT * P) if ahead > 0 else ahead

    def done(self) -> float:
        """Mark the end of the current tick's work; returns its duration [s]."""
        if self._last_start is None:
            return 0.0
        d = self.clock.now() - self._last_start
        self._duration.append(d)
        return d

    def count(self, duration_s: float) -> None:
        """Count a tick that ran unscheduled (headless), of this duration [s]."""
        self.headless = True
        self._index += 1
        self._duration.append(duration_s)

    @property
    def overrun_share(self) -> float:
        """The share of the last `OVERRUN_WINDOW_S` of scheduled ticks that overran (0 with
        none yet)."""
        return sum(self._late) / len(self._late) if self._late else 0.0

    @property
    def sustained_overrun(self) -> bool:
        """The window is full and at least `SUSTAINED_OVERRUN` of it overran."""
        full = len(self._late) == self._late.maxlen
        return full and self.overrun_share >= SUSTAINED_OVERRUN

    def restart(self) -> None:
        """Start the schedule afresh at the next `wait` (statistics are kept)."""
        self._next_s = None
        self._last_start = None
        self._ahead_s = 0.0
        self._ready.clear()
        self._last_on_frame = True

    @property
    def ticks(self) -> int:
        return self._index

    def reset_stats(self) -> None:
        """Forget the statistics so far (after a warm-up), keep the schedule."""
        self._jitter.clear()
        self._duration.clear()
        self._late.clear()
        self.overruns = 0
        self._index = 0
        self.frame_ticks = 0

    def summary(self) -> dict[str, float | int]:
        """Jitter and duration statistics [ms] over the recent history, and counts: ticks,
        overruns, the overrun share of the last window and whether it is sustained, the
        share of ticks that started on a new frame (following the camera); a headless
        run's has `headless`, durations and no jitter."""
        out: dict[str, float | int] = {"ticks": self._index, "overruns": self.overruns}
        if self.headless:
            out["headless"] = True
        else:
            out["overrun_share"] = round(self.overrun_share, 4)
            out["overrun_window_s"] = OVERRUN_WINDOW_S
            out["sustained_overrun"] = self.sustained_overrun
            if self.frame_ticks:
                out["on_frame_share"] = round(self.frame_ticks / max(1, self._index), 4)
        for name, values in (("jitter_ms", self._jitter), ("tick_ms", self._duration)):
            if values:
                a = np.asarray(values) * 1e3
                out[f"{name}_p50"] = round(float(np.median(a)), 3)
                out[f"{name}_p99"] = round(float(np.percentile(a, 99)), 3)
                out[f"{name}_max"] = round(float(a.max()), 3)
        return out
