"""The one record of a tick, and its JSON form in a session's `ticks.jsonl`.

The loop publishes one immutable `TickRecord` per tick: observers (the browser view, the
demo operator, a recorder, a test) all receive the same object, and a recorded session reads
back into the same type, so every consumer handles one shape. It holds the arbitration's own
`ArbitrationStep` and the plant's `PlantStep` as they are (nothing is copied into another
shape), so a new field of either reaches the recording and the view without an edit here
beyond its encoding.

JSON form (schema `dsteleop.session/5`; `recordings/README.md` lists the keys): states are
flat lists, position (3), rotation matrix row-major (9), openness (F); per-dimension arrays
are lists of 6 + F values; task events are "kind" or "kind:detail"; the robot's joint
positions (`joints`, and `joints_reset` beside `X_reset`) a list in the order of the
metadata's `joint_names` [rad, or m for a prismatic joint: `joint_units`]. Inputs of a
replay (the hand, the robot's side, the times) keep full precision; outputs (the
arbitration, the command) keep 10 significant digits; landmarks 4 decimals. A robot that is
not told its goal (`--goal infer`) records its belief each tick (`belief`: the candidates'
names, their probabilities, the MAP, the confidence per dimension and joint; 10 significant
digits). Older schemas are read too. Schema 4 differs from 5 only in the belief (4 recorded
none: its records read back with `belief` None). Schema 3 differs from 4 only in the joints
(3 recorded none: its records read back with `joints` None). Schema 2 differs from 3 only in
the metadata (3 lists the session's episodes, `session.episodes`) and in the status of ticks
after the outcome (`finished`; 2 said `lost`). Schema 1 (before the typed record): its notes
and task events were one list, told apart here by kind.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.ports import HumanInput, PlantStep
from dsteleop.arbitration import STEP_ARRAYS, ArbitrationStep, HandState, Mode
from dsteleop.errors import FormatError, InputError
from dsteleop.robot.task import EventKind, Outcome, Phase, TaskEvent
from dsteleop.tracking.types import HandSample

Array = NDArray[np.float64]

SCHEMA = "dsteleop.session/5"
READABLE = (
    "dsteleop.session/1",
    "dsteleop.session/2",
    "dsteleop.session/3",
    "dsteleop.session/4",
    SCHEMA,
)


class Status(str, enum.Enum):
    """What drives the robot this tick."""

    TRACKING = "tracking"  # the operator's fresh hand, through the arbitration
    LOST = "lost"  # no usable hand: the robot halts (or stands still)
    ASSIST = "assist"  # no usable hand, `--lost-policy assist`: the policy at reduced speed
    FINISHED = "finished"  # the task has its outcome (the reason says which): the robot halts


@dataclass(frozen=True)
class RecordingStatus:
    """What a running recording has done so far, for the view (not written to the ticks).

    Attributes:
        folder: the session folder.
        elapsed_s: loop time since the recording started [s].
        episodes: episodes ended so far.
        episode: the open episode's index, or None between episodes.
    """

    folder: str
    elapsed_s: float
    episodes: int
    episode: int | None


@dataclass(frozen=True)
class BeliefRecord:
    """The robot's belief over its goal candidates after a tick (`--goal infer`;
    docs/METHOD.md §10).

    Attributes:
        names: the candidates (the utensils in the pick phase, "bin" in the place phase).
        probability: (K,) the belief over them, each >= belief.epsilon, summing to 1.
        map_index: the MAP candidate (the robot's goal).
        confidence: (6 + F,) the robot's confidence c_i in each dimension of that goal.
        confidence_joint: its confidence in the whole goal at once.
    """

    names: tuple[str, ...]
    probability: Array
    map_index: int
    confidence: Array
    confidence_joint: float

    @property
    def map_name(self) -> str:
        return self.names[self.map_index]

    def of(self, name: str) -> float:
        """The probability of candidate `name` (nan if it is not one)."""
        return float(self.probability[self.names.index(name)]) if name in self.names else math.nan


@dataclass(frozen=True)
class TickRecord:
    """Everything about one tick (module docstring).

    Attributes:
        k: tick index since the last task reset.
        t_s: loop time of the tick's start [s] (monotonic, or the headless clock).
        mode: arbitration mode.
        dims: dimension names (x, y, z, roll, pitch, yaw, fingers).
        status: what drove the robot; reason: why there was no usable hand ("" if there was).
        hand: the human input the loop used this tick, or None.
        step: the arbitration of this tick, or None when it did not run (stale input).
        X_goal: the goal the robot knew this tick, or None once the task was done.
        X_next: the state commanded to the robot.
        U_cmd: the velocity commanded (U_out while tracking; the halt ramp or the assist
            action otherwise) [m/s, rad/s, 1/s].
        plant: what the robot and the task reported after the tick.
        X_human: the last fresh hand pose (the operator's command in the view), or None.
        notes: operator changes applied at the start of the tick ("mode:S", "reset", ...).
        timing: loop timing [ms]: jitter, tick duration, latencies from capture.
        X_reset: the state the robot reset to at the start of this tick (the first tick and
            after a task reset), else None; a replay against the recorded robot starts there.
        joints_reset: the robot's joint positions at that reset [rad, or m for a prismatic
            joint] (`Robot.joint_names` order), or None (no reset, or no joints reported).
        stopped: the operator's stop was latched during this tick (the page's Stop, until
            Resume): the robot halts as for a lost hand; written only when True.
        belief: the belief over the goal candidates of a robot not told its goal, after
            this tick, or None (told, or the task done).
        recording: the recording in progress, or None (for the view; not written).
    """

    k: int
    t_s: float
    mode: Mode
    dims: tuple[str, ...]
    status: Status
    reason: str
    hand: HumanInput | None
    step: ArbitrationStep | None
    X_goal: HandState | None
    X_next: HandState
    U_cmd: Array
    plant: PlantStep
    X_human: HandState | None = None
    notes: tuple[str, ...] = ()
    timing: Mapping[str, float] = field(default_factory=dict)
    X_reset: HandState | None = None
    joints_reset: Array | None = None
    stopped: bool = False
    belief: BeliefRecord | None = None
    recording: RecordingStatus | None = None

    @property
    def X_current(self) -> HandState:
        """The robot's achieved state after the tick."""
        return self.plant.X_current

    @property
    def phase(self) -> Phase:
        return self.plant.phase

    @property
    def outcome(self) -> Outcome | None:
        return self.plant.outcome

    @property
    def arbitrated(self) -> bool:
        return self.step is not None


# --- states and events --------------------------------------------------------------------


def pack(X: HandState | None) -> list[float] | None:
    """A state as one flat list: position (3), rotation matrix row-major (9), openness (F)."""
    if X is None:
        return None
    return [*X.position.tolist(), *X.rotation.ravel().tolist(), *X.openness.tolist()]


def unpack(v: list[float] | None) -> HandState | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if a.ndim != 1 or a.size < 12:
        raise FormatError(f"a state needs at least 12 numbers, got {a.size}")
    return HandState(a[0:3], a[3:12].reshape(3, 3), a[12:])


def pack_joints(q: Array) -> list[float]:
    """Joint positions as a list (full precision: an input of a replay)."""
    return np.asarray(q, dtype=np.float64).tolist()


def unpack_joints(v: list[float | None] | None) -> Array | None:
    """Joint positions from their list (null, i.e. not measured, as NaN), or None."""
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if a.ndim != 1:
        raise FormatError(f"joint positions must be a flat list, got shape {a.shape}")
    return a


def encode_event(e: TaskEvent) -> str:
    return f"{e.kind.value}:{e.detail}" if e.detail else e.kind.value


def decode_event(text: str, t_s: float) -> TaskEvent | None:
    """A task event from "kind[:detail]", or None when it is not one (an operator note)."""
    kind, _, detail = text.partition(":")
    try:
        return TaskEvent(EventKind(kind), t_s, detail)
    except ValueError:
        return None


def encode_outcome(o: Outcome | None) -> dict[str, Any] | None:
    if o is None:
        return None
    return {"success": o.success, "reason": o.reason, "time_s": o.time_s, "utensil": o.utensil}


def decode_outcome(v: Any, events: tuple[TaskEvent, ...] = ()) -> Outcome | None:
    if v is None or v == "":
        return None
    if isinstance(v, str):  # schema 1: "success" or "failure"; the reason is its event's
        reason = next((e.detail for e in events if e.kind.value == v), "")
        return Outcome(v == "success", reason, math.nan, "")
    t = v.get("time_s")
    return Outcome(
        bool(v["success"]), str(v["reason"]), math.nan if t is None else float(t), str(v["utensil"])
    )


def _sig(a: Array | list[float] | None) -> list[float] | None:
    """Outputs for the record, to 10 significant digits."""
    if a is None:
        return None
    return [float(f"{x:.10g}") for x in np.asarray(a, dtype=np.float64).ravel().tolist()]


def _rounded(a: Array | None, decimals: int = 4) -> list[list[float]] | None:
    """Landmarks for the record: display data, 4 decimals (0.1 mm, 1e-4 of the image)."""
    return None if a is None else np.round(a, decimals).tolist()


# --- encode --------------------------------------------------------------------------------


def _encode_hand(inp: HumanInput | None) -> dict[str, Any] | None:
    if inp is None:
        return None
    hand: dict[str, Any] = {
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
            size=[s.width_px, s.height_px],
        )
    return hand


def encode(r: TickRecord) -> dict[str, Any]:
    """The JSON object of one tick (module docstring)."""
    out: dict[str, Any] = {
        "k": r.k,
        "t": r.t_s,
        "mode": r.mode.value,
        "status": r.status.value,
        "reason": r.reason,
        "phase": r.plant.phase.value,
        "outcome": encode_outcome(r.plant.outcome),
        "events": [encode_event(e) for e in r.plant.events],
        "notes": list(r.notes),
        "hand": _encode_hand(r.hand),
        "X_human": pack(r.X_human),
        # The robot's side at full precision: a replay against the recorded robot reads it
        # back as its input (`plants.recorded.RecordedRobot`).
        "X_current": pack(r.plant.X_current),
        # Only from a robot that reports joints (schema 3's records hold none).
        **({} if r.plant.joints is None else {"joints": pack_joints(r.plant.joints)}),
        "X_goal": pack(r.X_goal),
        "X_next": _sig(pack(r.X_next)),
        "U_cmd": _sig(r.U_cmd),
        "arb": None if r.step is None else {k: _sig(getattr(r.step, k)) for k in STEP_ARRAYS},
        "timing": {k: round(v, 4) for k, v in r.timing.items()},
    }
    if r.stopped:
        out["stopped"] = True
    if r.belief is not None:
        out["belief"] = encode_belief(r.belief)
    if r.X_reset is not None:
        out["X_reset"] = pack(r.X_reset)
        if r.joints_reset is not None:
            out["joints_reset"] = pack_joints(r.joints_reset)
    return out


def encode_belief(b: BeliefRecord) -> dict[str, Any]:
    """A belief as its JSON object (`TickRecord.belief`)."""
    return {
        "names": list(b.names),
        "p": _sig(b.probability),
        "map": b.map_name,
        "c": _sig(b.confidence),
        "c_joint": float(f"{b.confidence_joint:.10g}"),
    }


# --- decode --------------------------------------------------------------------------------


def decode_belief(v: dict[str, Any] | None) -> BeliefRecord | None:
    """A belief from its JSON object (None: none recorded)."""
    if v is None:
        return None
    names = tuple(str(n) for n in v["names"])
    p = np.asarray(v["p"], dtype=np.float64)
    if p.shape != (len(names),):
        raise FormatError(f"belief: {p.size} probabilities for {len(names)} candidates")
    return BeliefRecord(
        names,
        p,
        names.index(str(v["map"])),
        np.asarray(v["c"], dtype=np.float64),
        float(v["c_joint"]),
    )


def _decode_hand(h: dict[str, Any] | None) -> HumanInput | None:
    if h is None:
        return None
    sample = None
    if "p_cam" in h and "detected" in h:
        nan3 = np.full(3, np.nan)
        lm = h.get("landmarks")
        wl = h.get("world_landmarks")
        size = h.get("size") or [0, 0]
        sample = HandSample(
            seq=int(h["seq"]),
            t_capture_s=float(h["t_capture"]),
            t_tracked_s=float(h["t_tracked"]),
            detected=bool(h["detected"]),
            handedness=h.get("handedness"),
            score=float(h.get("score") or 0.0),
            landmarks_image=None if lm is None else np.asarray(lm, dtype=np.float64),
            landmarks_world=None if wl is None else np.asarray(wl, dtype=np.float64),
            p_cam_palm_m=np.asarray(h["p_cam"], dtype=np.float64),
            R_cam_palm=np.asarray(h["R_cam"], dtype=np.float64).reshape(3, 3),
            openness=np.asarray(h["openness"], dtype=np.float64),
            raw_p_cam_palm_m=nan3,
            raw_R_cam_palm=np.full((3, 3), np.nan),
            raw_openness=np.full(5, np.nan),
            width_px=int(size[0]),
            height_px=int(size[1]),
        )
    return HumanInput(
        seq=int(h["seq"]),
        t_capture_s=float(h["t_capture"]),
        t_tracked_s=float(h["t_tracked"]),
        X_human=unpack(h.get("X")),
        reason=str(h.get("reason", "")),
        sample=sample,
    )


def _decode_step(arb: dict[str, Any] | None, X_next: HandState) -> ArbitrationStep | None:
    if not arb:
        return None
    arrays = {k: np.asarray(arb[k], dtype=np.float64) for k in STEP_ARRAYS}
    return ArbitrationStep(**arrays, X_next=X_next)


def decode(d: dict[str, Any], dims: tuple[str, ...]) -> TickRecord:
    """A tick record from its JSON object (any readable schema).

    Raises:
        InputError: a key is missing or a value is malformed (the message names it).
    """
    try:
        t = float(d["t"])
        texts = [str(e) for e in d.get("events", [])]
        decoded = [(x, decode_event(x, t)) for x in texts]
        events = tuple(e for _, e in decoded if e is not None)
        notes = tuple(d.get("notes", ())) + tuple(x for x, e in decoded if e is None)
        X_current = unpack(d["X_current"])
        X_next = unpack(d.get("X_next")) or X_current
        assert X_current is not None and X_next is not None
        plant = PlantStep(
            X_current=X_current,
            phase=Phase(d.get("phase", "pick")),
            events=events,
            outcome=decode_outcome(d.get("outcome"), events),
            joints=unpack_joints(d.get("joints")),
        )
        return TickRecord(
            k=int(d["k"]),
            t_s=t,
            mode=Mode.parse(str(d.get("mode", "DS"))),
            dims=dims,
            status=Status(d.get("status", "tracking")),
            reason=str(d.get("reason", "")),
            hand=_decode_hand(d.get("hand")),
            step=_decode_step(d.get("arb"), X_next),
            X_goal=unpack(d.get("X_goal")),
            X_next=X_next,
            U_cmd=np.asarray(d.get("U_cmd") or np.zeros(len(dims)), dtype=np.float64),
            plant=plant,
            X_human=unpack(d.get("X_human")),
            notes=notes,
            timing={k: float(v) for k, v in (d.get("timing") or {}).items() if v is not None},
            X_reset=unpack(d.get("X_reset")),
            joints_reset=unpack_joints(d.get("joints_reset")),
            stopped=bool(d.get("stopped", False)),
            belief=decode_belief(d.get("belief")),
        )
    except (KeyError, TypeError, ValueError, AssertionError) as exc:
        raise InputError(f"malformed tick record ({type(exc).__name__}: {exc})") from None
