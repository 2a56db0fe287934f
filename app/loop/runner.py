"""The 30 Hz teleoperation loop: hand -> arbitration -> robot, one tick at a time, at a fixed
rate or following the camera's frames (`timing.RateClock`).

`TeleopLoop` owns the clock and the tick's side effects; the decisions are the pure
functions of `tick.py`. One tick:

    requests  <- controls (stop/resume, mode, calibrate, reset, params, recording), taken once
    input     <- hand.poll(now), re-anchored when the hand comes back
    goal      <- task.goal(), or for a robot not told its goal the MAP of the belief over
                 task.candidates() updated from the hand (`inference.GoalInference`), with
                 its confidence per dimension
    decide    -- tick.decide: arbitration, or the halt ramp / assist while lost (the hand),
                 or the halt ramp while the robot is lost (its state missing or older than
                 ports.ROBOT_STALE_S) or the operator's stop is latched
    robot     -> robot.apply(X_next, seq, now); robot.state(now): X_current and joints
    task      <- task.update(state): phase, events, outcome (not while the robot is lost)
    absorb    -- tick.absorb: the robot's and the task's report, segments, the history
    record    -> one TickRecord to every observer (and to the recorder, when recording)

Everything a loop talks to is given to its constructor (the composition root is
`app/compose/`): the hand, the robot, the task, the clock, the observers, the outputs,
where the operator history persists and where "Start recording" writes. The session's
lifecycle (a folder opened, each record written and split into episodes, the outputs told)
is `session.recording.Recording`'s; the loop says when.
"""

from __future__ import annotations

import dataclasses
import datetime
import gc
import json
import logging
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.loop import tick
from dsteleop.app.loop.broadcast import Broadcaster
from dsteleop.app.loop.config import LoopConfig
from dsteleop.app.loop.controls import Controls, Requests
from dsteleop.app.loop.inference import GoalInference, Inferred
from dsteleop.app.loop.timing import (
    OVERRUN_WINDOW_S,
    MonotonicClock,
    RateClock,
    TickTiming,
    put_this_thread_first,
)
from dsteleop.app.ports import (
    ROBOT_LOST,
    ROBOT_STALE_S,
    Clock,
    HandInput,
    HumanInput,
    Observer,
    Output,
    PlantStep,
    Robot,
    RobotState,
    Task,
    TaskStep,
)
from dsteleop.app.session.recording import Recording
from dsteleop.app.session.schema import TickRecord, encode_event
from dsteleop.app.session.writer import HistoryFile, new_session_folder
from dsteleop.arbitration import HandState, Mode, OperatorHistory, dim_names, make_arbiter
from dsteleop.arbitration.arbiters import compile_kernels
from dsteleop.errors import DsteleopError
from dsteleop.robot.task import Phase

log = logging.getLogger(__name__)
Array = NDArray[np.float64]


def _joints_of(rs: RobotState) -> Array | None:
    """The joints a robot state reports, for the record; None from a robot without joints."""
    return rs.joints if rs.joints.size else None


class TeleopLoop:
    """The fixed-rate loop (module docstring). One thread calls `tick`/`run`.

    Args:
        config: loop settings.
        hand: the operator's hand.
        robot: the robot.
        task: the task (judging the robot's measured state each tick).
        clock: time source (`ManualClock` for headless runs and tests).
        observers: called with every tick's record, in the loop's thread (must not block).
        history: the operator's previous attempts (eq 6); default: loaded from `history_file`.
        history_file: where the history persists (saved at the end of each segment).
        outputs: what is written beside the loop's sessions (`ports.Output`: the camera's
            video, a live LeRobot dataset, a Rerun recording): each observes every tick after
            the observers, and hears of each session and recorded episode.
        record_root: where a recording requested through `controls` is written.
        meta: extra metadata for recordings (source description, seeds, ...).
        follow_frames: in real time (`run`), each tick follows the hand's new frames when
            the hand has them (`HandInput.arrivals`); False: the fixed-rate schedule.
    """

    def __init__(
        self,
        config: LoopConfig,
        hand: HandInput,
        robot: Robot,
        task: Task,
        clock: Clock | None = None,
        *,
        observers: Sequence[Observer] = (),
        history: OperatorHistory | None = None,
        history_file: HistoryFile | None = None,
        outputs: Sequence[Output] = (),
        record_root: Path | None = None,
        meta: dict[str, Any] | None = None,
        follow_frames: bool = True,
    ) -> None:
        self.config = config
        self.follow_frames = follow_frames
        self.hand = hand
        self.robot = robot
        self.task = task
        self.clock = clock or MonotonicClock()
        self.rate = RateClock(config.rate_hz, self.clock)
        self.controls = Controls()
        self.broadcaster = Broadcaster()
        self._observers: tuple[Observer, ...] = (self.broadcaster, *observers, *outputs)
        self._history_file = history_file
        if history is None:
            history = history_file.load() if history_file is not None else OperatorHistory()
        self._recording = Recording(outputs)
        self.record_root = record_root
        self.meta = dict(meta or {})
        self.dims = dim_names(robot.finger_names)
        self._notes: list[str] = []
        self._t_outcome: float | None = None
        self._stop = threading.Event()
        self._overrun_said = False
        # Frame-to-command latency [ms] of each new frame (its first command), recent ticks.
        self.latency_ms: deque[float] = deque(maxlen=18000)
        # Capture to tracked [ms] of the same frames: the tracker's own time per frame.
        self.tracking_ms: deque[float] = deque(maxlen=18000)
        self._latency_seq = -1
        self._last_input: HumanInput | None = None
        self._hist_key: tuple[int, Any] | None = None
        self._hist_term: Array | None = None
        self.mode = config.mode
        self.arbiter = make_arbiter(config.mode, config.arbitration)
        self.events_log: list[tuple[int, str]] = []
        self._seq = 0  # the robot's command sequence number (one per tick, never reset)
        self._robot_lost = ""  # why the robot cannot be driven ("" while it can)
        self._robot_lost_since: float | None = None  # the first tick of the current loss
        self._trial_t0: float | None = None  # the first tick of the current trial
        #: Ticks on which the robot was lost (its state missing or stale), since the start.
        self.robot_lost_ticks = 0
        #: Why `run` stopped on a lost robot ("" if it did not; `run`'s robot_lost_limit_s).
        self.robot_lost_end = ""
        self._joints: Array | None = None  # the robot's last measured joints (None: none)
        #: The belief over the goal candidates of a robot not told its goal.
        self.inference = GoalInference()
        #: The operator's stop is latched (Stop pressed, Resume not yet): the robot halts.
        self.stopped = False
        #: Stops the operator pressed since the start (a Stop while stopped is not counted).
        self.stops = 0
        reset = self._reset_world(None)
        self.state = tick.start(reset.X, self.arbiter, history)
        self.utensil = str(task.describe().get("utensil", ""))
        self.tick_index = 0
        self._reset_state: RobotState | None = reset  # in the next record

    # --- state -----------------------------------------------------------------------

    @property
    def history(self) -> OperatorHistory:
        return self.state.history

    @property
    def outcome(self) -> str:
        """ "", "success" or "failure"."""
        o = self.state.outcome
        return "" if o is None else ("success" if o.success else "failure")

    @property
    def X_current(self) -> HandState:
        return self.state.X_current

    def _set_mode(self, mode: Mode) -> None:
        self.mode = mode
        self.arbiter = make_arbiter(mode, self.config.arbitration)
        self.state = dataclasses.replace(
            self.state, filter=self.arbiter.initial_state(len(self.dims))
        )

    def _reset_world(self, utensil: str | None) -> RobotState:
        """The task set up again, then the robot home: its state there."""
        self.task.reset(utensil)
        self.inference.reset()
        rs = self.robot.reset(self.clock.now())
        self._robot_lost = ""
        self._robot_lost_since = None
        self._trial_t0 = None
        self._last_step = TaskStep(Phase.PICK)
        self._joints = _joints_of(rs)
        return rs

    def _reset_task(self, utensil: str | None) -> None:
        reset = self._reset_world(utensil)
        self.state = tick.start(reset.X, self.arbiter, self.state.history)
        self.utensil = str(self.task.describe().get("utensil", utensil or ""))
        self._reset_state = reset
        self.tick_index = 0
        self.events_log = []
        self._t_outcome = None

    def _reset_due(self, now_s: float) -> bool:
        """`reset_after_s` has passed since the outcome (auto reset on)."""
        after = self.config.reset_after_s
        if after <= 0 or self.state.outcome is None:
            return False
        if self._t_outcome is None:
            self._t_outcome = now_s
        return now_s - self._t_outcome >= after

    def _apply(self, req: Requests) -> None:
        """Apply the operator's requests (in the loop's thread); each is recorded as a note."""
        if req.empty:
            return
        if req.stop is not None and req.stop != self.stopped:
            # Latched: the halt of a lost hand (tick.decide's `halt`) until Resume.
            self.stopped = req.stop
            self.stops += req.stop
            self._notes.append("stop" if req.stop else "resume")
            if req.stop:
                log.warning("stopped by the operator: the robot halts until Resume")
            else:
                log.info("resumed by the operator")
        if req.params:
            self._set_params(req.params)
        if req.mode is not None:
            try:
                self._set_mode(Mode.parse(req.mode))
                self._notes.append(f"mode:{self.mode.value}")
            except DsteleopError as exc:
                log.warning("%s", exc)
        if req.calibrate:
            self.hand.calibrate()
            self._notes.append("calibrate")
        if req.reset:
            self._reset_task(req.utensil)
            self._notes.append("reset")
        if req.record is False:
            self.stop_recording()
        elif req.record is True:
            self._record_requested()

    def _record_requested(self) -> None:
        if self.record_root is None:
            log.warning("recording requested, but no recording folder is set (--record DIR)")
            return
        utensil = str(self.task.describe().get("utensil", "task"))
        try:
            self.start_recording(new_session_folder(self.record_root, self.mode.value, utensil))
        except DsteleopError as exc:
            log.error("could not start recording: %s", exc)

    def _set_params(self, params: dict[str, Any]) -> None:
        params = dict(params)
        noise = params.pop("goal_noise_m", None)
        if noise is not None:
            self.task.set_goal_noise(float(noise))
        if params:
            try:
                cfg = self.config.arbitration.replace(**params)
            except DsteleopError as exc:
                log.warning("ignored parameter change %s: %s", params, exc)
                return
            self.config = dataclasses.replace(self.config, arbitration=cfg)
            self._set_mode(self.mode)
        changed = {**params, **({} if noise is None else {"goal_noise_m": noise})}
        self._notes.append("params:" + json.dumps(changed, sort_keys=True))

    # --- recording -------------------------------------------------------------------

    def session_meta(self) -> dict[str, Any]:
        return {
            **self.meta,
            "loop": self.config.to_dict(),
            "mode": self.mode.value,
            "dims": list(self.dims),
            "source": self.hand.describe(),
            "mapping": self.hand.mapping_config(),
            "plant": self.task.describe(),
            "robot": self.robot.describe(),
            # The joints of each tick's `joints` and `joints_reset`, once: names and units.
            "joint_names": list(self.robot.joint_names),
            "joint_units": list(self.robot.joint_units),
            "operator_history": self.history.to_dict(),
            # Where it persists: the file and the hash of its content now, or None (empty,
            # kept nowhere: the default).
            "operator_history_file": (
                None if self._history_file is None else self._history_file.describe()
            ),
        }

    def start_recording(self, folder: Path, extra: dict[str, Any] | None = None) -> Path:
        """Record a run of the task into `folder` (a new session folder) from the next tick.

        A recording starts with the task, so that a replay can rebuild the same world: if
        the loop has already ticked, the task is reset first. Call from the loop's thread
        (other threads use `controls.set_recording(True)`).
        """
        self.stop_recording()
        if self.tick_index > 0:
            self._reset_task(None)
        meta = {
            **self.session_meta(),
            "started_at": datetime.datetime.now(datetime.timezone.utc).isoformat(),
            **(extra or {}),
        }
        return self._recording.start(Path(folder), meta)

    def stop_recording(self) -> None:
        """Close the recording: the open episode ends "stopped", meta.json is completed."""
        self._recording.stop({"timing": self.rate.summary()})

    @property
    def recording(self) -> Path | None:
        """The open session's folder, or None."""
        return self._recording.folder

    @property
    def recordings(self) -> list[Path]:
        """Every session folder this loop recorded into, in order."""
        return self._recording.folders

    # --- the tick --------------------------------------------------------------------

    def tick(self, t_start_s: float | None = None, jitter_s: float = 0.0) -> TickRecord:
        """Run one tick at the clock's current time; returns (and publishes) its record."""
        now = self.clock.now() if t_start_s is None else t_start_s
        requests = self.controls.take()
        if self._reset_due(now) and not requests.reset:
            requests = dataclasses.replace(requests, reset=True)  # the next trial
        self._apply(requests)
        if self._trial_t0 is None:
            self._trial_t0 = now
        reset_state, self._reset_state = self._reset_state, None
        inp = self.hand.poll(now)
        self._last_input = inp
        candidates = self.task.candidates()
        goal = self.task.goal() if candidates is None else None
        fresh = (
            inp is not None
            and inp.X_human is not None
            and (goal is not None or candidates is not None)
            and not tick.staleness(inp, now, self.config)
        )
        if fresh and self.state.lost:
            # First hand of the task: it maps onto the robot's pose. Back after a loss: it
            # maps to where the command was when it was lost. No jump either way.
            assert inp is not None
            inp = self.hand.reanchor(inp, tick.anchor_target(self.state))
        inferred: Inferred | None = None
        t_goal = time.perf_counter()
        if candidates is not None:
            X_h = inp.X_human if fresh and inp is not None else None
            X_h_prev = None if self.state.lost else self.state.X_human_prev
            inferred = self.inference.step(
                candidates, self.config.arbitration.belief, self.state.X_current, X_h, X_h_prev
            )
            goal = inferred.goal
        goal_ms = (time.perf_counter() - t_goal) * 1e3
        ended = self.hand.end_reason if self.hand.finished else ""
        self.state, decision = tick.decide(
            self.state,
            self.config,
            self.arbiter,
            inp,
            goal,
            now,
            self._history_term(),
            ended,
            self._robot_lost or (tick.STOPPED if self.stopped else ""),
            None if inferred is None else inferred.confidence,
            None if inferred is None else inferred.confidence_joint,
        )
        t_arb = self.clock.now()
        self._seq += 1
        self.robot.apply(decision.X_next, self._seq, now)
        result = self._observe_robot(now)
        self.robot_lost_ticks += bool(self._robot_lost)
        t_cmd = self.clock.now()
        self.state, segment_ended = tick.absorb(self.state, result, self.arbiter)
        if segment_ended and self._history_file is not None:
            self._history_file.save(self.state.history)
        notes = tuple(self._notes)
        self._notes.clear()
        for e in (*notes, *(encode_event(ev) for ev in result.events)):
            self.events_log.append((self.tick_index, e))
        timing = self._timing(inp, now, t_arb, t_cmd, jitter_s)
        if inferred is not None:
            timing["goal_ms"] = goal_ms  # the belief's update and reading, this tick
        record = TickRecord(
            k=self.tick_index,
            t_s=now,
            mode=self.mode,
            dims=self.dims,
            status=decision.status,
            reason=decision.reason,
            hand=inp,
            step=decision.step,
            X_goal=goal,
            X_next=decision.X_next,
            U_cmd=decision.U_cmd,
            plant=result,
            X_human=self.state.X_human_last,
            notes=notes,
            timing=timing,
            X_reset=None if reset_state is None else reset_state.X,
            joints_reset=None if reset_state is None else _joints_of(reset_state),
            stopped=self.stopped,
            belief=None if inferred is None else inferred.record,
        )
        record = self._recording.put(record, self.utensil)
        for observer in self._observers:
            observer.observe(record)
        self.tick_index += 1
        return record

    def _observe_robot(self, now_s: float) -> PlantStep:
        """The robot's measured state and the task's judgement of it; while the robot is
        lost (no state, or one older than ROBOT_STALE_S), the last state and no judgement,
        and the next ticks halt."""
        rs: RobotState | None = self.robot.state(now_s)
        if rs is None or not now_s - rs.stamp_s <= ROBOT_STALE_S:
            if not self._robot_lost:
                log.warning(
                    "%s: no robot state for %.2f s: halting", self.robot.name, ROBOT_STALE_S
                )
            self._robot_lost = ROBOT_LOST
            if self._robot_lost_since is None:
                self._robot_lost_since = now_s
            return PlantStep(
                self.state.X_current,
                self._last_step.phase,
                (),
                self._last_step.outcome,
                joints=self._joints,
            )
        if self._robot_lost:
            log.info("%s: robot state again", self.robot.name)
        self._robot_lost = ""
        self._robot_lost_since = None
        self._last_step = self.task.update(rs)
        self._joints = _joints_of(rs)
        return PlantStep.of(rs.X, self._last_step, self._joints)

    def robot_lost_for(self, now_s: float) -> float:
        """How long the robot has been lost, since the first tick that found its state missing
        or stale (that is, ROBOT_STALE_S after its last state) [s]; 0 while it is not."""
        since = self._robot_lost_since
        return 0.0 if since is None else now_s - since

    def _lost_too_long(
        self, now_s: float, lost_limit_s: float | None, time_limit_s: float | None
    ) -> str:
        """Why a run must stop on a lost robot ("" while it need not): lost for longer than
        `lost_limit_s`, or still lost when the trial reached `time_limit_s` without an outcome
        (the task cannot judge a trial it cannot see, so its own timeout does not come)."""
        lost_s = self.robot_lost_for(now_s)
        if not self._robot_lost or self.state.outcome is not None:
            return ""
        if lost_limit_s is not None and lost_s > lost_limit_s:
            return (
                f"{self.robot.name}: {ROBOT_LOST}: no robot state for "
                f"{lost_s + ROBOT_STALE_S:.1f} s (more than {lost_limit_s:g} s); the run stopped "
                "without an outcome"
            )
        t0 = self._trial_t0
        if time_limit_s is not None and t0 is not None and now_s - t0 >= time_limit_s:
            return (
                f"{self.robot.name}: {ROBOT_LOST} at the time limit ({time_limit_s:g} s) with no "
                f"outcome; no robot state for the last {lost_s + ROBOT_STALE_S:.1f} s"
            )
        return ""

    def _history_term(self) -> Array | None:
        key = (len(self.history), self.config.arbitration)
        if self._hist_key != key:
            F = len(self.robot.finger_names)
            self._hist_term = self.history.term(F, self.config.arbitration.still_offset(F))
            self._hist_key = key
        return self._hist_term

    def _timing(
        self, inp: HumanInput | None, now: float, t_arb: float, t_cmd: float, jitter_s: float
    ) -> dict[str, float]:
        out = {
            "rate_hz": self.config.rate_hz,
            "jitter_ms": jitter_s * 1e3,
            "tick_ms": (t_cmd - now) * 1e3,
            "overruns": float(self.rate.overruns),
            "overrun_share": self.rate.overrun_share,
        }
        if inp is not None:
            out["capture_to_tracked_ms"] = (inp.t_tracked_s - inp.t_capture_s) * 1e3
            out["capture_to_arbitrated_ms"] = (t_arb - inp.t_capture_s) * 1e3
            out["capture_to_commanded_ms"] = (t_cmd - inp.t_capture_s) * 1e3
            if inp.seq != self._latency_seq:
                self._latency_seq = inp.seq
                self.latency_ms.append(out["capture_to_commanded_ms"])
                self.tracking_ms.append(out["capture_to_tracked_ms"])
        return out

    # --- running ---------------------------------------------------------------------

    def run(
        self,
        max_ticks: int | None = None,
        until_outcome: bool = False,
        until_finished: bool = False,
        tail_s: float = 0.5,
        robot_lost_limit_s: float | None = None,
        time_limit_s: float | None = None,
    ) -> None:
        """Tick in real time until `stop()`, `max_ticks`, or (optionally) an outcome or
        the end of a file source (plus `tail_s` [s], so the halt shows in the record, as in
        `run_headless`), or a lost robot: lost for longer than `robot_lost_limit_s`, or
        lost when the trial reaches `time_limit_s` [s] without an outcome (`robot_lost_end`
        says which; None: no such limit). The hand input starts delivering (a file starts
        playing) just before the first tick. Each tick follows the hand's new frames when it
        has them (`follow_frames` and `HandInput.arrivals`: a camera, a video), else the fixed rate
        (`timing.RateClock`); it never waits for a frame past its nominal time beyond the
        moment the input it has goes stale, so the halt comes when it would at the fixed rate.

        While it runs, the interpreter hands the GIL between threads every 0.5 ms instead of
        5 ms, so capture and tracking threads delay a due tick by at most about that much.
        Everything built before the first tick (the models, the robot, the view) is moved
        out of the garbage collector's sight (`gc.freeze`): a full collection then scans only
        what the session allocates, instead of pausing every thread for tens of milliseconds
        over the whole heap (measured: up to 26 ms, and a missed tick). Every other thread of
        the process runs a few niceness steps below the loop's (`timing.put_this_thread_first`:
        its own capture, tracking, viewer and recorder threads would otherwise delay a due tick
        by several milliseconds on two cores). The compiled arbitration is loaded before the
        schedule starts.
        """
        n = 0
        compile_kernels()  # loaded from numba's cache now (~0.5 s), not at the first tick
        gc.collect()
        gc.freeze()
        self.hand.start()
        put_this_thread_first()
        self.rate.restart()  # the schedule starts now, not where an earlier run left it
        switch = sys.getswitchinterval()
        sys.setswitchinterval(0.0005)
        end_at: float | None = None
        try:
            while not self._stop.is_set():
                timing = self.wait_for_tick()
                self.tick(timing.t_start_s, timing.jitter_s)
                self.rate.done()
                self._say_overrun()
                n += 1
                if max_ticks is not None and n >= max_ticks:
                    break
                if until_outcome and self.outcome:
                    break
                why = self._lost_too_long(timing.t_start_s, robot_lost_limit_s, time_limit_s)
                if why:
                    self.robot_lost_end = why  # the caller reports it
                    break
                if until_finished and end_at is None and self.hand.finished:
                    end_at = timing.t_start_s + tail_s
                if end_at is not None and timing.t_start_s >= end_at:
                    break
        finally:
            sys.setswitchinterval(switch)

    def wait_for_tick(self) -> TickTiming:
        """Wait until the next real-time tick is due: following the hand's new frames when it
        has them (`follow_frames`, `HandInput.arrivals`), else at the fixed rate; never past
        the moment the input of the last tick goes stale (`run`)."""
        arrivals = self.hand.arrivals if self.follow_frames else None
        return self.rate.wait(arrivals, self._stale_at())

    def _stale_at(self) -> float:
        """When the input of the last tick goes stale (`tick.staleness`) [s]; -inf without."""
        inp = self._last_input
        if inp is None:
            return -math.inf
        return inp.t_capture_s + self.config.input_delay_s + self.config.stale_limit_s

    def _say_overrun(self) -> None:
        """Log once when the loop stops keeping its rate (a sustained overrun share), and
        once when it keeps it again."""
        sustained = self.rate.sustained_overrun
        if sustained == self._overrun_said:
            return
        self._overrun_said = sustained
        if sustained:
            log.warning(
                "the loop does not keep %g Hz: %.0f%% of the ticks of the last %g s started "
                "more than a period late (a busy machine, or a rate too high for it)",
                self.config.rate_hz,
                100 * self.rate.overrun_share,
                OVERRUN_WINDOW_S,
            )
        else:
            log.info("the loop keeps %g Hz again", self.config.rate_hz)

    def run_headless(self, max_ticks: int, tail_s: float = 0.5) -> None:
        """Tick on the (manual) clock as fast as possible until an outcome, the end of a file
        source (plus `tail_s`, so the halt shows in the record), or `max_ticks`."""
        dt = self.config.dt_s
        end_at: float | None = None
        self.hand.start()
        for k in range(max_ticks):
            t = k * dt
            self.clock.sleep_until(t)
            w0 = time.perf_counter()
            self.tick(t)
            self.rate.count(time.perf_counter() - w0)
            if self.outcome:
                break
            if end_at is None and self.hand.finished:
                end_at = t + tail_s
            if end_at is not None and t >= end_at:
                break

    def stop(self) -> None:
        self._stop.set()

    def timing_summary(self) -> dict[str, float | int]:
        """Rate-clock statistics plus, over the same new frames, frame-to-command latency
        percentiles and the tracker's own time per frame (capture to tracked) [ms]."""
        out = self.rate.summary()
        if self.tracking_ms:
            a = np.asarray(self.tracking_ms)
            out["tracking_ms_p50"] = round(float(np.median(a)), 3)
            out["tracking_ms_p95"] = round(float(np.percentile(a, 95)), 3)
        if self.latency_ms:
            a = np.asarray(self.latency_ms)
            out["latency_ms_p50"] = round(float(np.median(a)), 3)
            out["latency_ms_p95"] = round(float(np.percentile(a, 95)), 3)
            out["latency_ms_p99"] = round(float(np.percentile(a, 99)), 3)
        return out

    def close(self) -> None:
        """Close the recording (complete), the hand source and the robot."""
        self.stop()
        try:
            self.stop_recording()
        finally:
            try:
                self.hand.close()
            finally:
                try:
                    self.robot.close()
                finally:
                    self.task.close()
