"""The 30 Hz teleoperation loop: hand -> arbitration -> robot, one fixed-rate tick at a time.

One tick (DESIGN.md §1, §5):

    requests  <- controls (mode, calibrate, reset, params, recording), taken once
    input     <- hand.poll(now): the newest mapped hand at least `input_delay_s` old
    fresh?    -- valid hand and age <= stale_limit_s (monotonic clock, less the delay)
    tracking: U_out, X_next <- arbiter(X_human, X_current, X_goal, ...)       eq (1)-(8)
    lost, policy "halt":   U_cmd = U_last * ramp, ramp 1 -> 0 over `halt_ramp_s`, then hold:
                           the command is 0 within stale_limit_s + halt_ramp_s of the
                           last fresh sample, and a stale command is never repeated
    lost, policy "assist": alpha = 1 on every dimension at `assist_speed` of the policy's
                           speed, until the hand returns or the goal is reached
    robot     <- plant.apply(X_next): IK, physics, task events; X_current read back
    observers <- one Snapshot (one-slot mailboxes: a slow observer never slows the loop)
    recorder  <- the tick record (its own writer thread, nothing dropped)

Eq (2) integrates the commanded reference: X_next = integrate(X_ref, U_cmd, dt), with X_ref
the previous tick's X_next, kept within `max_lead_m` / `max_lead_rad` of the achieved palm
X_current (read back from the simulation; the policy, P(R) and psi use it). Integrating from
the achieved pose instead loses the position controller's lag every tick: the robot fell
about a third short of the hand's motion in manual mode in a first version. The bound keeps a
blocked robot (pressing on the table) from winding the reference up.

When the hand returns after being lost, the mapping is re-anchored so the hand maps to where
the operator's command was when it was lost, and the first fresh tick has U_human = 0: the
robot does not jump. Capture and tracking run in their own threads (the tracking stream).
"""

from __future__ import annotations

import dataclasses
import enum
import json
import logging
import math
import queue
import sys
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.controls import Controls, Requests
from dsteleop.app.hand_input import HandInput, HumanInput, is_stale
from dsteleop.app.observers import Broadcaster, Snapshot
from dsteleop.app.recording import SessionWriter
from dsteleop.app.timing import Clock, MonotonicClock, RateClock
from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    ArbitrationStep,
    HandState,
    Mode,
    OperatorHistory,
    dim_names,
    make_arbiter,
    scalar,
)
from dsteleop.arbitration.arbiters import FilterState
from dsteleop.errors import DsteleopError

log = logging.getLogger(__name__)
Array = NDArray[np.float64]


class LostPolicy(str, enum.Enum):
    """What the robot does while the hand is lost."""

    HALT = "halt"
    ASSIST = "assist"


@dataclass(frozen=True)
class LoopConfig:
    """Loop settings, recorded with every session.

    Attributes:
        rate_hz: control rate [Hz].
        mode: arbitration mode at start.
        stale_limit_s: hand input older than this is stale [s] (DESIGN.md §5: 0.1).
        halt_ramp_s: the halt ramp brings the commanded speed to 0 in this time [s].
        lost_policy: `halt` (default) or `assist`.
        assist_speed: fraction of the policy's speed used while assisting (0, 1].
        assist_goal_tolerance_m: assisting stops this close to the goal [m].
        input_delay_s: injected delay on the human input [s] (the paper's study used one).
        max_lead_m: the commanded reference may lead the achieved palm by at most this [m]
            (anti-windup when the robot is blocked; module docstring).
        max_lead_rad: ... and by at most this angle [rad].
        arbitration: the arbitration hyper-parameters.
    """

    rate_hz: float = 30.0
    mode: Mode = Mode.DS
    stale_limit_s: float = 0.1
    halt_ramp_s: float = 0.066
    lost_policy: LostPolicy = LostPolicy.HALT
    assist_speed: float = 0.5
    assist_goal_tolerance_m: float = 0.01
    input_delay_s: float = 0.0
    max_lead_m: float = 0.03
    max_lead_rad: float = 0.25
    arbitration: ArbitrationConfig = field(default_factory=ArbitrationConfig)

    def __post_init__(self) -> None:
        for name in (
            "rate_hz",
            "stale_limit_s",
            "halt_ramp_s",
            "assist_speed",
            "assist_goal_tolerance_m",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise DsteleopError(f"{name} must be a positive number, got {v!r}")
        if not (np.isfinite(self.input_delay_s) and self.input_delay_s >= 0):
            raise DsteleopError(f"input_delay_s must be >= 0, got {self.input_delay_s!r}")
        if self.assist_speed > 1:
            raise DsteleopError(f"assist_speed must be in (0, 1], got {self.assist_speed!r}")

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["mode"] = self.mode.value
        d["lost_policy"] = self.lost_policy.value
        d["arbitration"] = self.arbitration.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LoopConfig:
        d = dict(d)
        d["mode"] = Mode.parse(d.get("mode", "DS"))
        d["lost_policy"] = LostPolicy(d.get("lost_policy", "halt"))
        d["arbitration"] = ArbitrationConfig.from_dict(d.get("arbitration", {}))
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


@dataclass(frozen=True)
class PlantStep:
    """What the robot and the task report after a tick."""

    X_current: HandState
    phase: str
    events: tuple[str, ...] = ()
    outcome: str = ""
    segment_changed: bool = False
    scene: Any = None


class Plant(Protocol):
    """The robot and its task as the loop sees them (see `dsteleop.app.plant`)."""

    finger_names: tuple[str, ...]

    def reset(self, utensil: str | None = None) -> HandState: ...

    def goal(self) -> HandState | None: ...

    def phase(self) -> str: ...

    def apply(self, X_next: HandState) -> PlantStep: ...

    def set_goal_noise(self, sigma_m: float) -> None: ...

    def describe(self) -> dict[str, Any]: ...

    def scene_description(self) -> Any: ...

    def close(self) -> None: ...


def pack(X: HandState | None) -> list[float] | None:
    """A state as one flat list: position (3), rotation matrix row-major (9), openness (F)."""
    if X is None:
        return None
    return [*X.position.tolist(), *X.rotation.ravel().tolist(), *X.openness.tolist()]


def unpack(v: list[float] | None) -> HandState | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    return HandState(a[0:3], a[3:12].reshape(3, 3), a[12:])


def _sig(a: Array | list[float] | None) -> list[float] | None:
    """Outputs for the record, to 10 significant digits (the replay's input, the hand, and
    all times keep full precision)."""
    if a is None:
        return None
    return [float(f"{x:.10g}") for x in np.asarray(a, dtype=np.float64).ravel().tolist()]


def _rounded(a: Array | None, decimals: int = 4) -> list[list[float]] | None:
    """Landmarks for the record: display data, 4 decimals (0.1 mm, 1e-4 of the image)."""
    return None if a is None else np.round(a, decimals).tolist()


class _Recorder:
    """Writes tick records on its own thread: a slow disk never stalls the loop."""

    def __init__(self, writer: SessionWriter) -> None:
        self.writer = writer
        self._q: queue.SimpleQueue[dict[str, Any] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="dsteleop-recorder", daemon=True)
        self._thread.start()

    def put(self, record: dict[str, Any]) -> None:
        self._q.put(record)

    def _run(self) -> None:
        while (rec := self._q.get()) is not None:
            self.writer.write_tick(rec)

    def close(self, extra_meta: dict[str, Any]) -> None:
        self._q.put(None)
        self._thread.join()
        self.writer.close(extra_meta)


class TeleopLoop:
    """The fixed-rate loop (module docstring). One thread calls `tick`/`run`.

    Args:
        config: loop settings.
        hand: the human input.
        plant: the robot and task.
        clock: time source (`ManualClock` for tests and replay).
        history: the operator's previous attempts (eq 6); updated at the end of each segment.
        meta: extra metadata for recordings (source description, seeds, ...).
    """

    def __init__(
        self,
        config: LoopConfig,
        hand: HandInput,
        plant: Plant,
        clock: Clock | None = None,
        history: OperatorHistory | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        self.config = config
        self.hand = hand
        self.plant = plant
        self.clock = clock or MonotonicClock()
        self.rate = RateClock(config.rate_hz, self.clock)
        self.controls = Controls()
        self.broadcaster = Broadcaster()
        self.history = history or OperatorHistory()
        self.meta = dict(meta or {})
        self.dims = dim_names(plant.finger_names)
        self.on_segment_end: Callable[[OperatorHistory], None] | None = None
        # Called with the session folder when a recording starts, and with None when it stops
        # (the camera-frame tee of `--record-video` listens here).
        self.on_recording: Callable[[Path | None], None] | None = None
        self.record_root: Path | None = None  # where `controls.set_recording(True)` records
        # Called with the robot's start state after every task reset (the demo restarts).
        self.on_task_reset: Callable[[HandState], None] | None = None
        self._notes: list[str] = []  # operator changes, recorded as events of the next tick
        self._recorder: _Recorder | None = None
        self._stop = threading.Event()
        # Frame-to-command latency [ms] of each new frame (its first command), recent ticks.
        self.latency_ms: deque[float] = deque(maxlen=18000)
        self._latency_seq = -1
        self._set_mode(config.mode)
        self._reset_task(None)

    # --- state -----------------------------------------------------------------------

    def _set_mode(self, mode: Mode) -> None:
        self.mode = mode
        self.arbiter = make_arbiter(mode, self.config.arbitration)
        self._filter: FilterState = self.arbiter.initial_state(len(self.dims))

    def _reset_task(self, utensil: str | None) -> None:
        self.X_current = self.plant.reset(utensil)
        if self.on_task_reset is not None:
            self.on_task_reset(self.X_current)
        self.X_ref = self.X_current
        self.X_prev = self.X_current
        self.X_start = self.X_current
        self.X_human: HandState | None = None
        self.X_human_prev: HandState | None = None
        self.X_human_start: HandState | None = None
        self.X_human_last: HandState | None = None  # last fresh hand pose
        self.tick_index = 0
        self.lost = True
        self.reason = "no input yet"
        self.t_lost_s: float | None = None
        self.U_last = np.zeros(len(self.dims))
        self.U_at_loss = self.U_last
        self.outcome = ""
        self.events_log: list[tuple[int, str]] = []
        self._last_step: ArbitrationStep | None = None
        self._filter = self.arbiter.initial_state(len(self.dims))
        self._reset_state: HandState | None = self.X_current  # recorded with the next tick

    def _apply(self, req: Requests) -> None:
        """Apply the operator's requests (in the loop's thread); each is recorded as an event."""
        if req.empty:
            return
        if req.params:
            self._set_params(req.params)
        if req.mode is not None:
            try:
                self._set_mode(Mode.parse(req.mode))
                self._notes.append(f"mode:{self.mode.value}")
            except ValueError as exc:
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
        import datetime

        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        utensil = self.plant.describe().get("utensil", "task")
        folder = self.record_root / f"{stamp}-{self.mode.value}-{utensil}"
        k = 1
        while folder.exists():
            k += 1
            folder = self.record_root / f"{stamp}-{self.mode.value}-{utensil}-{k}"
        try:
            self.start_recording(folder)
        except DsteleopError as exc:
            log.error("could not start recording: %s", exc)

    def _set_params(self, params: dict[str, Any]) -> None:
        params = dict(params)
        noise = params.pop("goal_noise_m", None)
        if noise is not None:
            self.plant.set_goal_noise(float(noise))
        if params:
            try:
                cfg = self.config.arbitration.replace(**params)
            except (TypeError, ValueError) as exc:
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
            "plant": self.plant.describe(),
            "operator_history": self.history.to_dict(),
        }

    def start_recording(self, folder: Path, extra: dict[str, Any] | None = None) -> Path:
        """Record a trial into `folder` (a new session folder) from the next tick.

        A recording is one run of the task from its start, so that a replay can rebuild the
        same world: if the loop has already ticked, the task is reset first. Call from the
        loop's thread (other threads use `controls.set_recording(True)`).
        """
        self.stop_recording()
        if self.tick_index > 0:
            self._reset_task(None)
        import datetime

        meta = {
            **self.session_meta(),
            "started_at": datetime.datetime.now(datetime.timezone.utc).isoformat(),
            **(extra or {}),
        }
        self._recorder = _Recorder(SessionWriter(folder, meta))
        if self.on_recording is not None:
            self.on_recording(Path(folder))
        log.info("recording to %s", folder)
        return Path(folder)

    def stop_recording(self) -> None:
        if self._recorder is not None:
            if self.on_recording is not None:
                self.on_recording(None)
            self._recorder.close(
                {"outcome": self.outcome, "events": self.events_log, "timing": self.rate.summary()}
            )
            log.info(
                "recording closed: %s (%d ticks)",
                self._recorder.writer.folder,
                self._recorder.writer.n_ticks,
            )
            self._recorder = None

    @property
    def recording(self) -> Path | None:
        return None if self._recorder is None else self._recorder.writer.folder

    # --- the tick --------------------------------------------------------------------

    def tick(self, t_start_s: float | None = None, jitter_s: float = 0.0) -> Snapshot:
        """Run one tick at the clock's current time and publish its snapshot."""
        now = self.clock.now() if t_start_s is None else t_start_s
        cfg = self.config
        dt = cfg.dt_s
        self._apply(self.controls.take())

        inp = self.hand.poll(now)
        reason = is_stale(inp, now, cfg.input_delay_s, cfg.stale_limit_s)
        goal = self.plant.goal()
        step: ArbitrationStep | None = None
        t_arb = now
        if not reason and inp is not None and inp.X_human is not None and goal is not None:
            if self.lost:
                # First hand of the task: it maps onto the robot's pose. Back after a loss:
                # it maps to where the command was when it was lost. No jump either way.
                inp = self.hand.reanchor(inp, self.X_human_last or self.X_current)
            X_h = inp.X_human
            assert X_h is not None
            if self.lost or self.X_human_prev is None:
                self.X_human_prev = X_h  # first fresh tick: U_human = 0
            if self.X_human_start is None:
                self.X_human_start = X_h
            self.lost, self.reason, self.t_lost_s = False, "", None
            self._filter, step = self.arbiter.step(
                self._filter,
                ArbitrationInput(
                    X_h,
                    self.X_human_prev,
                    self.X_human_start,
                    self.X_current,
                    self.X_prev,
                    self.X_start,
                    goal,
                    dt,
                    self._history_term(),
                ),
            )
            t_arb = self.clock.now()
            U_cmd = step.U_out
            self.X_human_prev = self.X_human = self.X_human_last = X_h
            status = "tracking"
        else:
            if not self.lost:
                self.t_lost_s, self.U_at_loss = now, self.U_last
            self.lost, self.reason = True, reason or "task finished"
            t_lost = now if self.t_lost_s is None else self.t_lost_s
            if cfg.lost_policy is LostPolicy.ASSIST and goal is not None:
                U_cmd, step, status = self._assist(goal, dt)
            else:
                ramp = max(0.0, 1.0 - (now - t_lost) / cfg.halt_ramp_s)
                U_cmd = self.U_at_loss * ramp
                status = "lost"
            self.X_human_prev = None

        self.U_last = np.asarray(U_cmd)
        X_next = self._advance_reference(self.U_last, dt)
        result = self.plant.apply(X_next)
        t_cmd = self.clock.now()
        self.X_prev, self.X_current = self.X_current, result.X_current
        if result.outcome and not self.outcome:
            self.outcome = result.outcome
            self._end_segment()  # the place segment ends with the outcome
        elif result.segment_changed:
            self._end_segment()
        events = (*self._notes, *result.events)
        self._notes.clear()
        for e in events:
            self.events_log.append((self.tick_index, e))

        shown = step or self._last_step
        if step is not None:
            self._last_step = step
        zeros = np.zeros(len(self.dims))
        timing = self._timing(inp, now, t_arb, t_cmd, jitter_s)
        if inp is not None:
            timing["capture_to_published_ms"] = (self.clock.now() - inp.t_capture_s) * 1e3
            if inp.seq != self._latency_seq:
                self._latency_seq = inp.seq
                self.latency_ms.append(timing["capture_to_commanded_ms"])
        snap = Snapshot(
            tick=self.tick_index,
            t_s=now,
            mode=self.mode.value,
            status=status,
            reason=self.reason,
            dims=self.dims,
            alpha=shown.alpha if shown else zeros,
            P_human=shown.P_human if shown else zeros,
            P_robot=shown.P_robot if shown else zeros,
            B=shown.B if shown else zeros,
            psi_human=shown.psi_human if shown else zeros,
            psi_robot=shown.psi_robot if shown else zeros,
            U_human=shown.U_human if shown else zeros,
            U_robot=shown.U_robot if shown else zeros,
            U_out=shown.U_out if shown else zeros,
            X_human=self.X_human_last,
            X_current=self.X_current,
            X_goal=goal if goal is not None else self.X_current,
            phase=result.phase,
            outcome=self.outcome,
            events=events,
            timing=timing,
            hand=inp,
            scene=result.scene,
            X_next=X_next,
            U_cmd=self.U_last,
            arbitrated=step is not None,
        )
        self.broadcaster.publish(snap)
        if self._recorder is not None:
            self._recorder.put(self._record(snap, step))
        self._reset_state = None
        self.tick_index += 1
        return snap

    def _advance_reference(self, U: Array, dt: float) -> HandState:
        """Eq (2) on the commanded reference, bounded to stay near the achieved palm.

        Scalar maths (`arbitration.scalar`): this runs every tick on one state.
        """
        u = U.tolist()
        p_ref, R_ref, g_ref = (
            self.X_ref.position.tolist(),
            self.X_ref.rotation.tolist(),
            self.X_ref.openness.tolist(),
        )
        p = [p_ref[i] + u[i] * dt for i in range(3)]
        R = scalar.exp_times((u[3] * dt, u[4] * dt, u[5] * dt), R_ref)
        g = [min(max(gi + ui * dt, 0.0), 1.0) for gi, ui in zip(g_ref, u[6:])]
        cur_p, cur_R = self.X_current.position.tolist(), self.X_current.rotation.tolist()
        dp = [p[i] - cur_p[i] for i in range(3)]
        n = math.sqrt(dp[0] ** 2 + dp[1] ** 2 + dp[2] ** 2)
        if n > self.config.max_lead_m:
            k = self.config.max_lead_m / n
            p = [cur_p[i] + dp[i] * k for i in range(3)]
        w = scalar.log_rel(R, cur_R)
        a = math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
        if a > self.config.max_lead_rad:
            k = self.config.max_lead_rad / a
            R = scalar.exp_times((w[0] * k, w[1] * k, w[2] * k), cur_R)
        self.X_ref = HandState(np.array(p), np.array(R), np.array(g))
        return self.X_ref

    def _history_term(self) -> Array:
        key = (len(self.history), self.config.arbitration)
        if getattr(self, "_hist_key", None) != key:
            F = len(self.plant.finger_names)
            self._hist_term = self.history.term(F, self.config.arbitration.eps(F))
            self._hist_key = key
        return self._hist_term

    def _assist(self, goal: HandState, dt: float) -> tuple[Array, ArbitrationStep | None, str]:
        """alpha = 1 on every dimension at reduced speed, until the goal is reached."""
        if (
            np.linalg.norm(goal.position - self.X_current.position)
            < self.config.assist_goal_tolerance_m
        ):
            return np.zeros(len(self.dims)), None, "assist"
        X_h = self.X_human_last or self.X_current
        auto = make_arbiter(Mode.AUTONOMOUS, self.config.arbitration)
        _, step = auto.step(
            auto.initial_state(len(self.dims)),
            ArbitrationInput(
                X_h,
                X_h,
                self.X_human_start or X_h,
                self.X_current,
                self.X_prev,
                self.X_start,
                goal,
                dt,
            ),
        )
        return step.U_robot * self.config.assist_speed, step, "assist"

    def _end_segment(self) -> None:
        """A pick or place segment ended: remember the attempt, restart the segment."""
        if self.X_human_start is not None and self.X_human_last is not None:
            self.history = self.history.add(self.X_human_start, self.X_human_last)
            if self.on_segment_end is not None:
                self.on_segment_end(self.history)
        self.X_start = self.X_current
        self.X_human_start = self.X_human_last

    def _timing(
        self, inp: HumanInput | None, now: float, t_arb: float, t_cmd: float, jitter_s: float
    ) -> dict[str, float]:
        out = {
            "rate_hz": self.config.rate_hz,
            "jitter_ms": jitter_s * 1e3,
            "tick_ms": (t_cmd - now) * 1e3,
            "overruns": float(self.rate.overruns),
        }
        if inp is not None:
            out["capture_to_tracked_ms"] = (inp.t_tracked_s - inp.t_capture_s) * 1e3
            out["capture_to_arbitrated_ms"] = (t_arb - inp.t_capture_s) * 1e3
            out["capture_to_commanded_ms"] = (t_cmd - inp.t_capture_s) * 1e3
        return out

    def _record(self, snap: Snapshot, step: ArbitrationStep | None) -> dict[str, Any]:
        inp: HumanInput | None = snap.hand
        hand: dict[str, Any] | None = None
        if inp is not None:
            hand = {
                "seq": inp.seq,
                "t_capture": inp.t_capture_s,
                "t_tracked": inp.t_tracked_s,
                "X": pack(inp.X_human),
                "reason": inp.reason,
            }
            s = inp.sample
            if s is not None:
                hand.update(
                    detected=s.detected,
                    handedness=s.handedness,
                    score=s.score,
                    landmarks=_rounded(s.landmarks_image),
                    world_landmarks=_rounded(s.landmarks_world),
                    p_cam=s.p_cam_palm_m.tolist(),
                    R_cam=s.R_cam_palm.ravel().tolist(),
                    openness=s.openness.tolist(),
                )
        arb = None
        if step is not None:
            arb = {k: _sig(getattr(step, k)) for k in STEP_ARRAYS}
        extra = {} if self._reset_state is None else {"X_reset": pack(self._reset_state)}
        return {
            "k": snap.tick,
            "t": snap.t_s,
            "mode": snap.mode,
            "status": snap.status,
            "reason": snap.reason,
            "phase": snap.phase,
            "outcome": snap.outcome,
            "events": list(snap.events),
            "hand": hand,
            # The robot's side at full precision: a replay against the recorded robot reads
            # them back as its inputs (`replay.RecordedPlant`).
            "X_current": pack(snap.X_current),
            "X_goal": pack(snap.X_goal),
            "X_next": _sig(pack(snap.X_next)),
            "U_cmd": _sig(snap.U_cmd),
            "arb": arb,
            "timing": {k: round(v, 4) for k, v in snap.timing.items()},
            **extra,
        }

    # --- running ---------------------------------------------------------------------

    def run(self, max_ticks: int | None = None, until_outcome: bool = False) -> None:
        """Tick at the fixed rate until `stop()`, `max_ticks`, or (optionally) an outcome.

        While it runs, the interpreter hands the GIL between threads every 0.5 ms instead of
        5 ms, so capture and tracking threads delay a due tick by at most about that much.
        """
        n = 0
        switch = sys.getswitchinterval()
        sys.setswitchinterval(0.0005)
        try:
            while not self._stop.is_set():
                timing = self.rate.wait()
                self.tick(timing.t_start_s, timing.jitter_s)
                self.rate.done()
                n += 1
                if max_ticks is not None and n >= max_ticks:
                    break
                if until_outcome and self.outcome:
                    break
        finally:
            sys.setswitchinterval(switch)

    def stop(self) -> None:
        self._stop.set()

    def timing_summary(self) -> dict[str, float | int]:
        """Rate-clock statistics plus frame-to-command latency percentiles [ms]."""
        out = self.rate.summary()
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
                self.plant.close()
