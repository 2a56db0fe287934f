"""The loop's human input: the newest tracked hand, mapped into the robot base frame.

Every kind of hand source reaches the loop through one small interface, `HandInput`: a live
camera, a video, the synthetic operator (all through the tracking pipeline and the workspace
mapping) and a recorded session (its mapped hand, tick by tick). The loop cannot tell them
apart.

`poll(now)` never blocks: it returns the newest input that is at least `input_delay_s` old
(the paper's study injected a delay; default 0), or None when there is none yet.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from dsteleop.arbitration import HandState
from dsteleop.tracking.mapping import WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import FrameSource
from dsteleop.tracking.types import Frame, HandSample

NO_HAND = "no hand"
INVALID = "invalid hand data"


@dataclass(frozen=True)
class HumanInput:
    """One tracked-and-mapped hand sample.

    Attributes:
        seq: frame number of the source.
        t_capture_s: capture time [s] on the loop's clock.
        t_tracked_s: when tracking of the frame finished [s].
        X_human: the hand in the robot base frame with the robot's fingers, or None when
            there is no usable hand in this sample.
        reason: "" when `X_human` is usable, else why not ("no hand", "invalid hand data").
        sample: the tracker's sample (landmarks, camera-frame pose) for recording and the
            view; None for recorded input.
    """

    seq: int
    t_capture_s: float
    t_tracked_s: float
    X_human: HandState | None
    reason: str = ""
    sample: HandSample | None = None


class HandInput(Protocol):
    """What the loop needs of a hand source."""

    def poll(self, now_s: float) -> HumanInput | None: ...

    def reanchor(self, inp: HumanInput, X_target: HandState) -> HumanInput:
        """Make the hand of `inp` map to `X_target` from now on; return it re-mapped."""
        ...

    def calibrate(self) -> None:
        """Re-centre the mapping on the current hand without a jump."""
        ...

    def describe(self) -> str: ...

    def mapping_config(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


def _usable(X: HandState) -> bool:
    return X.is_finite() and bool(np.all((X.openness >= 0) & (X.openness <= 1)))


class TrackedHandInput:
    """Tracked hand samples through a `WorkspaceMapping`.

    Args:
        latest: returns the newest tracked sample at loop time `now` (or None): a
            `TrackingStream`'s `latest` for live sources (`from_stream`), or a synchronous
            reader for headless runs (`from_source`).
        mapping: camera -> robot mapping (owned by the loop's thread from here on).
        input_delay_s: hand samples reach the loop this much later than captured [s].
        description: the source, for logs and recordings.
        on_close: releases the source.
    """

    def __init__(
        self,
        latest: Callable[[float], HandSample | None],
        mapping: WorkspaceMapping,
        input_delay_s: float = 0.0,
        description: str = "hand source",
        on_close: Callable[[], None] | None = None,
        finished: Callable[[], bool] | None = None,
    ) -> None:
        self._latest = latest
        self._finished = finished
        self.mapping = mapping
        self.input_delay_s = input_delay_s
        self._description = description
        self._on_close = on_close
        self._last_seq = -1
        self._pending: deque[HandSample] = deque(maxlen=512)
        self._current: HandSample | None = None
        self._calibrate = False

    @classmethod
    def from_stream(
        cls, stream: TrackingStream, mapping: WorkspaceMapping, input_delay_s: float = 0.0
    ) -> TrackedHandInput:
        """Live: a started tracking stream (capture and tracking in their own threads)."""
        return cls(
            lambda _now: stream.latest(),
            mapping,
            input_delay_s,
            stream.source.describe(),
            stream.stop,
        )

    @classmethod
    def from_source(
        cls,
        source: FrameSource,
        tracker: HandTracker,
        mapping: WorkspaceMapping,
        input_delay_s: float = 0.0,
        t0_s: float = 0.0,
    ) -> TrackedHandInput:
        """Headless: frames are read and tracked in the caller's thread, up to loop time
        `now`, on the source's own clock (`t_capture_s` + `t0_s`); nothing is dropped."""
        reader = _SyncReader(source, tracker, t0_s)
        return cls(
            reader.latest,
            mapping,
            input_delay_s,
            source.describe(),
            reader.close,
            lambda: reader.finished,
        )

    def describe(self) -> str:
        return self._description

    @property
    def finished(self) -> bool:
        """The source has no more frames (a file that ended); False for live sources."""
        return self._finished is not None and self._finished()

    def mapping_config(self) -> dict[str, Any]:
        return dataclasses.asdict(self.mapping.config)

    def poll(self, now_s: float) -> HumanInput | None:
        s = self._latest(now_s)
        if s is not None and s.seq != self._last_seq:
            self._last_seq = s.seq
            self._pending.append(s)
        # The newest sample at least `input_delay_s` old becomes current.
        while self._pending and self._pending[0].t_capture_s <= now_s - self.input_delay_s:
            self._current = self._pending.popleft()
        if self._current is None:
            return None
        if self._calibrate and self._current.detected and self._current.has_pose:
            self.mapping.calibrate(self._current)
            self._calibrate = False
        return self._map(self._current)

    def _map(self, s: HandSample) -> HumanInput:
        if not s.detected:
            return HumanInput(s.seq, s.t_capture_s, s.t_tracked_s, None, NO_HAND, s)
        if not s.has_pose:
            return HumanInput(s.seq, s.t_capture_s, s.t_tracked_s, None, INVALID, s)
        X = self.mapping.map(s)
        if not _usable(X):
            return HumanInput(s.seq, s.t_capture_s, s.t_tracked_s, None, INVALID, s)
        return HumanInput(s.seq, s.t_capture_s, s.t_tracked_s, X, "", s)

    def reanchor(self, inp: HumanInput, X_target: HandState) -> HumanInput:
        s = inp.sample
        if s is None or not s.has_pose:
            return inp
        self.mapping.anchor_at(s.p_cam_palm_m, s.R_cam_palm, X_target)
        return self._map(s)

    def calibrate(self) -> None:
        self._calibrate = True

    def close(self) -> None:
        if self._on_close is not None:
            self._on_close()


class _SyncReader:
    """Reads and tracks a source's frames synchronously, up to a given time."""

    def __init__(self, source: FrameSource, tracker: HandTracker, t0_s: float) -> None:
        self.source, self.tracker, self.t0_s = source, tracker, t0_s
        source.open()
        self._next: Frame | None = source.read()
        self._sample: HandSample | None = None

    def latest(self, now_s: float) -> HandSample | None:
        while self._next is not None and self._next.t_capture_s + self.t0_s <= now_s + 1e-9:
            f = self._next
            shifted = dataclasses.replace(f, t_capture_s=f.t_capture_s + self.t0_s)
            s = self.tracker.process(shifted)
            self._sample = dataclasses.replace(s, t_tracked_s=shifted.t_capture_s)
            self._next = self.source.read()
        return self._sample

    @property
    def finished(self) -> bool:
        return self._next is None

    def close(self) -> None:
        self.source.close()
        self.tracker.close()


@dataclass(frozen=True)
class RecordedInput:
    """One tick's human input as a session recorded it."""

    t_tick_s: float
    inp: HumanInput | None


class RecordedHandInput:
    """Replays the mapped hand input a session recorded, tick by tick (headless replay).

    `poll(now)` returns the input recorded at the latest tick at or before `now`, so a replay
    run on the recorded tick times sees exactly what the live loop saw.
    """

    def __init__(self, records: Sequence[RecordedInput], description: str = "recording") -> None:
        self._records = list(records)
        self._times = [r.t_tick_s for r in self._records]
        self._description = description

    def describe(self) -> str:
        return self._description

    def mapping_config(self) -> dict[str, Any]:
        return {}

    def poll(self, now_s: float) -> HumanInput | None:
        k = bisect.bisect_right(self._times, now_s + 1e-9) - 1
        return None if k < 0 else self._records[k].inp

    def reanchor(self, inp: HumanInput, X_target: HandState) -> HumanInput:
        return inp  # the recorded hand is already the re-anchored one

    def calibrate(self) -> None:
        pass

    def close(self) -> None:
        pass


def is_stale(inp: HumanInput | None, now_s: float, delay_s: float, stale_limit_s: float) -> str:
    """Why the input cannot drive the robot now ("" when it can).

    Age is measured on the loop's monotonic clock from the capture time, less the injected
    delay: no input yet, no hand, invalid (NaN/inf) data, or a camera that stalled.
    """
    if inp is None:
        return "no input yet"
    if inp.X_human is None:
        return inp.reason or NO_HAND
    age = now_s - delay_s - inp.t_capture_s
    if not math.isfinite(age) or age > stale_limit_s:
        return "camera stalled"
    return ""
