"""The operator's hand from a tracked source: a camera, a video, the demo operator.

`TrackedHandInput` is the `ports.HandInput` of every source that goes through the tracking
pipeline: the newest `HandSample`, mapped into the robot base frame by a `WorkspaceMapping`.
`poll(now)` never blocks: it returns the newest input that is at least `input_delay_s` old
(the paper's study injected a delay; default 0), or None when there is none yet. A live
stream of camera frames (`from_stream` on a source with pixels) also tells the loop when a
new sample is ready (`arrivals`, `ports.InputArrivals`), so that its tick follows the camera.
"""

from __future__ import annotations

import bisect
import dataclasses
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from dsteleop.app.ports import INVALID, NO_HAND, HumanInput, InputArrivals
from dsteleop.arbitration import HandState
from dsteleop.tracking.mapping import WorkspaceMapping
from dsteleop.tracking.pipeline import HandTracker, TrackingStream
from dsteleop.tracking.sources import FrameSource
from dsteleop.tracking.types import Frame, HandSample


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
        finished: tells whether the source has ended (None: never).
        on_start: starts the source delivering (a live stream's threads), or None.
        end_reason: what the loop says once the input of a finished source is stale.
        arrivals: builds the `ports.InputArrivals` of this input (None: the loop paces it).

    Attributes:
        stream: the live tracking stream behind the input (`from_stream`; its `captured`,
            `dropped` and `tracked` counts say how many frames the tracker kept up with), or
            None.
    """

    def __init__(
        self,
        latest: Callable[[float], HandSample | None],
        mapping: WorkspaceMapping,
        input_delay_s: float = 0.0,
        description: str = "hand source",
        on_close: Callable[[], None] | None = None,
        finished: Callable[[], bool] | None = None,
        on_start: Callable[[], None] | None = None,
        end_reason: str = "video ended",
        arrivals: Callable[[TrackedHandInput], InputArrivals] | None = None,
    ) -> None:
        self._latest = latest
        self._finished = finished
        self._on_start = on_start
        self.end_reason = end_reason
        self.mapping = mapping
        self.input_delay_s = input_delay_s
        self._description = description
        self._on_close = on_close
        self._last_seq = -1
        self._pending: deque[HandSample] = deque(maxlen=512)
        self._current: HandSample | None = None
        self._calibrate = False
        self._arrivals = None if arrivals is None else arrivals(self)
        self.stream: TrackingStream | None = None

    @classmethod
    def from_stream(
        cls,
        stream: TrackingStream,
        mapping: WorkspaceMapping,
        input_delay_s: float = 0.0,
        follow: bool | None = None,
    ) -> TrackedHandInput:
        """Live: a tracking stream (capture and tracking in their own threads), started by
        `start()` (the loop's first tick) unless it already runs. With `follow` (default:
        when the source has pixels: a camera or a video, not the demo's synthetic hand) the
        input tells the loop when a new sample is ready (`arrivals`)."""
        if follow is None:
            follow = bool(getattr(stream.source, "has_pixels", True))

        def start() -> None:
            if not stream.started:
                stream.start()

        hand = cls(
            lambda _now: stream.latest(),
            mapping,
            input_delay_s,
            stream.source.describe(),
            stream.stop,
            lambda: stream.finished,
            on_start=start,
            arrivals=(lambda hand: _StreamArrivals(stream, hand)) if follow else None,
        )
        hand.stream = stream
        return hand

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

    def start(self) -> None:
        if self._on_start is not None:
            self._on_start()
            self._on_start = None

    @property
    def arrivals(self) -> InputArrivals | None:
        return self._arrivals

    def unreturned(self) -> list[HandSample]:
        """The kept samples newer than the one `poll` returned last, oldest first."""
        seq = -1 if self._current is None else self._current.seq
        return [s for s in self._pending if s.seq > seq]

    @property
    def newest_seen_seq(self) -> int:
        """The frame number of the newest sample kept (-1 before the first)."""
        return self._last_seq

    @property
    def finished(self) -> bool:
        """The source has no more frames (a file that ended); False for live sources."""
        return self._finished is not None and self._finished()

    def mapping_config(self) -> dict[str, Any]:
        return dataclasses.asdict(self.mapping.config)

    def keep(self, s: HandSample | None) -> None:
        """Keep a sample of the source until it is `input_delay_s` old (the first step of
        `poll`; the arrivals call it too, so that a sample seen while waiting is kept)."""
        if s is not None and s.seq != self._last_seq:
            self._last_seq = s.seq
            self._pending.append(s)

    def poll(self, now_s: float) -> HumanInput | None:
        self.keep(self._latest(now_s))
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


class _StreamArrivals:
    """`ports.InputArrivals` of a live tracking stream, on the monotonic clock (the live
    loop's): a sample is ready when tracked and at least the input delay old."""

    def __init__(self, stream: TrackingStream, hand: TrackedHandInput) -> None:
        self._stream = stream
        self._hand = hand

    def _ready_s(self, now_s: float) -> float | None:
        """When the input the hand would return next is ready: the newest sample not yet
        returned that is ready by `now_s`, else the earliest one to become ready."""
        self._hand.keep(self._stream.latest())
        samples = self._hand.unreturned()
        if not samples:
            return None
        delay = self._hand.input_delay_s
        ready = [max(s.t_tracked_s, s.t_capture_s + delay) for s in samples]
        past = [r for r in ready if r <= now_s]
        return max(past) if past else min(ready)

    def wait_newer(self, until_s: float) -> float | None:
        while True:
            now = time.monotonic()
            ready = self._ready_s(now)
            if ready is not None and ready <= now:
                return ready
            if now >= until_s:
                return None
            wake = until_s if ready is None else min(until_s, ready)  # the delay old
            if self._stream.finished:
                time.sleep(wake - now)  # nothing more will come
                continue
            # Block until the stream publishes a sample newer than any the hand has kept, or
            # a kept one is the delay old.
            self._stream.wait_for(self._hand.newest_seen_seq + 1, wake - now)


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


def replayed_samples(
    samples: Sequence[HandSample], mapping: WorkspaceMapping, description: str
) -> TrackedHandInput:
    """Samples tracked beforehand (a video tracked once), replayed on their capture times."""
    times = [s.t_capture_s for s in samples]
    end = times[-1] if times else 0.0
    seen = [-float("inf")]

    def latest(now_s: float) -> HandSample | None:
        seen[0] = now_s
        k = bisect.bisect_right(times, now_s + 1e-9) - 1
        return samples[k] if k >= 0 else None

    return TrackedHandInput(
        latest, mapping, description=description, finished=lambda: seen[0] >= end
    )
