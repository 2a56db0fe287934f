"""One object owns the loop's timing: a fixed-rate clock that measures itself.

`RateClock` schedules tick k at `t0 + k * period` on a monotonic clock. After a late tick it
re-anchors (the next deadline is one period after the late start) instead of bursting to catch
up, and counts the overrun. Every tick records its start-time jitter (actual start minus
scheduled start) and its duration; `summary()` gives medians and tail percentiles, and the
share of the last `OVERRUN_WINDOW_S` seconds of ticks that overran: at `SUSTAINED_OVERRUN`
or more the loop does not keep its rate (`sustained_overrun`), which the run's summary, the
log and the browser view's status say. A headless run (no schedule: as fast as the machine
allows) counts its ticks and their durations through `count`.

`ports.Clock` is the seam tests use to inject time: `MonotonicClock` is the real one; `ManualClock`
advances only when told to.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from dsteleop.app.ports import Clock

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
    """Timing of one tick [s]: when it was due, when it started, how late it started."""

    index: int
    t_due_s: float
    t_start_s: float
    jitter_s: float
    overrun: bool


#: The window over which the overrun share is measured [s].
OVERRUN_WINDOW_S = 10.0
#: An overrun share over the window at least this large is sustained: the rate is not kept.
SUSTAINED_OVERRUN = 0.1


class RateClock:
    """Fixed-rate scheduling with re-anchoring after overruns, and its own statistics.

    Args:
        rate_hz: ticks per second.
        clock: time source (monotonic by default).
        history: how many recent ticks the statistics cover.
    """

    def __init__(self, rate_hz: float, clock: Clock | None = None, history: int = 1800) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.period_s = 1.0 / rate_hz
        self.clock = clock or MonotonicClock()
        self._next_s: float | None = None
        self._index = 0
        self.overruns = 0
        self._jitter = deque[float](maxlen=history)
        self._duration = deque[float](maxlen=history)
        self._late = deque[bool](maxlen=max(1, round(OVERRUN_WINDOW_S * rate_hz)))
        self._last_start: float | None = None
        self.headless = False

    def wait(self) -> TickTiming:
        """Sleep until the next tick is due; return its timing."""
        now = self.clock.now()
        if self._next_s is None:
            self._next_s = now
        due = self._next_s
        if now < due:
            self.clock.sleep_until(due)
            now = self.clock.now()
        jitter = now - due
        overrun = jitter > self.period_s
        if overrun:
            # Late by more than a period: re-anchor on now instead of bursting to catch up.
            self.overruns += 1
            self._next_s = now + self.period_s
        else:
            self._next_s = due + self.period_s
        self._jitter.append(jitter)
        self._late.append(overrun)
        timing = TickTiming(self._index, due, now, jitter, overrun)
        self._index += 1
        self._last_start = now
        return timing

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

    def summary(self) -> dict[str, float | int]:
        """Jitter and duration statistics [ms] over the recent history, and counts: ticks,
        overruns, the overrun share of the last window and whether it is sustained;
        a headless run's has `headless`, durations and no jitter."""
        out: dict[str, float | int] = {"ticks": self._index, "overruns": self.overruns}
        if self.headless:
            out["headless"] = True
        else:
            out["overrun_share"] = round(self.overrun_share, 4)
            out["overrun_window_s"] = OVERRUN_WINDOW_S
            out["sustained_overrun"] = self.sustained_overrun
        for name, values in (("jitter_ms", self._jitter), ("tick_ms", self._duration)):
            if values:
                a = np.asarray(values) * 1e3
                out[f"{name}_p50"] = round(float(np.median(a)), 3)
                out[f"{name}_p99"] = round(float(np.percentile(a, 99)), 3)
                out[f"{name}_max"] = round(float(a.max()), 3)
        return out
