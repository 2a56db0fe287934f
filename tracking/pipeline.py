"""The tracking pipeline: frame -> landmarks -> one hand -> palm pose + openness -> filters.

`HandTracker.process(frame)` is the synchronous, per-frame step (no threads; it loads
MediaPipe on the first frame that has pixels, never at import). Frames that already carry
landmarks (the synthetic operator) skip the detector and go straight to the estimator.
`iter_samples` runs a source through a tracker frame by frame, as fast as possible (headless
replay: every frame, deterministic). `TrackingStream` runs capture and tracking in their own
threads for live use: one slot per stage, newest wins, drops are counted, `latest()` never
blocks.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
import time
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field

import numpy as np

from dsteleop.errors import ConfigError, ContractError
from dsteleop.tracking.detector import DetectorConfig, HandDetector, make_detector
from dsteleop.tracking.filters import HandFilterConfig, OneEuroFilter, SO3OneEuroFilter
from dsteleop.tracking.pose import CameraIntrinsics, PalmPose, PoseConfig, estimate_palm_pose
from dsteleop.tracking.selection import HandSelector, SelectionConfig
from dsteleop.tracking.sources import FrameSource
from dsteleop.tracking.synthetic import palm_facing_camera, synthesize_detection
from dsteleop.tracking.types import Array, Detection, Frame, HandSample

log = logging.getLogger(__name__)

_NAN3 = np.full(3, np.nan)
_NAN33 = np.full((3, 3), np.nan)
_NAN5 = np.full(5, np.nan)


@dataclass(frozen=True)
class TrackerConfig:
    """Everything the tracker needs, with documented defaults in each part.

    Attributes:
        detector: landmark model and thresholds (`detector.DetectorConfig`).
        pose: camera field of view, hand scale, openness range (`pose.PoseConfig`).
        filters: One Euro parameters (`filters.HandFilterConfig`).
        selection: which hand to follow (`selection.SelectionConfig`).
        mirrored: frames are flipped left-right (a selfie view): fixes handedness labels
            and reflects poses back into the physical camera frame.
        filter_reset_s: after this long without the hand [s], the filters restart from the
            next detection instead of gliding from where the hand was lost.
    """

    detector: DetectorConfig = field(default_factory=DetectorConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    filters: HandFilterConfig = field(default_factory=HandFilterConfig)
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    mirrored: bool = False
    filter_reset_s: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.filter_reset_s) and self.filter_reset_s >= 0):
            raise ConfigError(f"filter_reset_s must be >= 0, got {self.filter_reset_s!r}")


class HandTracker:
    """Synchronous per-frame tracker (module docstring). Not thread-safe: one owner.

    Args:
        config: tracker settings.
        detector: a ready detector (tests, or sharing); default: built from
            `config.detector` on the first frame with pixels.
    """

    def __init__(self, config: TrackerConfig | None = None, detector: HandDetector | None = None):
        self.config = config or TrackerConfig()
        self._detector = detector
        self._selector = HandSelector(self.config.selection)
        f = self.config.filters
        self._f_pos = OneEuroFilter(f.position)
        self._f_rot = SO3OneEuroFilter(f.orientation)
        self._f_open = OneEuroFilter(f.openness, per_component=True)
        self._intrinsics: CameraIntrinsics | None = None
        self._last_detected_t = -math.inf
        self._last: tuple[Array, Array, Array] = (_NAN3, _NAN33, _NAN5)

    @property
    def detector(self) -> HandDetector:
        """The landmark detector (loaded on first use)."""
        if self._detector is None:
            det_cfg = dataclasses.replace(self.config.detector, mirrored=self.config.mirrored)
            self._detector = make_detector(det_cfg)
        return self._detector

    def intrinsics(self, width_px: int, height_px: int) -> CameraIntrinsics:
        """Camera intrinsics for this image size (cached)."""
        k = self._intrinsics
        if k is None or (k.width_px, k.height_px) != (width_px, height_px):
            k = CameraIntrinsics.from_hfov(width_px, height_px, self.config.pose.hfov_deg)
            self._intrinsics = k
        return k

    def warm_up(self, width_px: int, height_px: int) -> None:
        """Load everything a frame with a hand needs now, then forget those frames.

        The detector's model, by running it on one blank frame of this size (~1 s); and the
        compiled SO(3) maths of the orientation filter (`arbitration.se3`, loaded from
        numba's cache at its first call: 0.5-2 s, which would otherwise fall on the second
        frame with a hand and stall a live loop), by tracking a synthetic hand twice.
        """
        blank = np.zeros((height_px, width_px, 3), dtype=np.uint8)
        self.detector.detect(blank, 0.0)
        camera = self.intrinsics(width_px, height_px)
        wanted = self.config.selection.hand
        hand = synthesize_detection(
            np.array([0.0, 0.0, 0.5]),
            palm_facing_camera(),
            np.full(5, 0.5),
            camera,
            handedness="Left" if wanted == "Left" else "Right",  # one the selector takes
        )
        for seq in range(2):
            frame = Frame(seq, seq / 30.0, width_px, height_px, detections=(hand,))
            self.process_detections(frame, (hand,))
        self.reset()

    def reset(self) -> None:
        """Forget the followed hand and the filter states."""
        self._selector.reset()
        for flt in (self._f_pos, self._f_rot, self._f_open):
            flt.reset()
        self._last_detected_t = -math.inf
        self._last = (_NAN3, _NAN33, _NAN5)

    def detect(self, frame: Frame) -> tuple[Detection, ...]:
        """All hands of a frame: its own landmarks, or the detector's on its pixels."""
        if frame.detections is not None:
            return frame.detections
        if frame.image is None:
            raise ContractError("frame has neither image nor detections")
        return tuple(self.detector.detect(frame.image, frame.t_capture_s))

    def process(self, frame: Frame) -> HandSample:
        """Track one frame (see module docstring) and return its sample."""
        return self.process_detections(frame, self.detect(frame))

    def process_detections(
        self, frame: Frame, detections: tuple[Detection, ...] | list[Detection]
    ) -> HandSample:
        """Select, estimate and filter given detections of `frame` (no detector)."""
        t = frame.t_capture_s
        aspect = frame.width_px / frame.height_px
        chosen = self._selector.select(detections, t, aspect)
        raw: PalmPose | None = None
        if chosen is not None:
            raw = estimate_palm_pose(
                chosen,
                self.intrinsics(frame.width_px, frame.height_px),
                self.config.pose,
                mirrored=self.config.mirrored,
            )
            if not raw.is_finite():
                log.debug("frame %d: degenerate landmarks, treated as no hand", frame.seq)
                raw, chosen = None, None
        if raw is not None and chosen is not None:
            if t - self._last_detected_t > self.config.filter_reset_s:
                for flt in (self._f_pos, self._f_rot, self._f_open):
                    flt.reset()
            self._last_detected_t = t
            if self.config.filters.enabled:
                self._last = (
                    self._f_pos(raw.p_cam_palm_m, t),
                    self._f_rot(raw.R_cam_palm, t),
                    np.clip(self._f_open(raw.openness, t), 0.0, 1.0),
                )
            else:
                self._last = (raw.p_cam_palm_m, raw.R_cam_palm, raw.openness)
        p, R, g = self._last
        return HandSample(
            seq=frame.seq,
            t_capture_s=t,
            t_tracked_s=time.monotonic(),
            detected=chosen is not None,
            handedness=chosen.handedness if chosen is not None else None,
            score=chosen.score if chosen is not None else 0.0,
            landmarks_image=chosen.landmarks_image if chosen is not None else None,
            landmarks_world=chosen.landmarks_world if chosen is not None else None,
            p_cam_palm_m=p.copy(),
            R_cam_palm=R.copy(),
            openness=g.copy(),
            raw_p_cam_palm_m=raw.p_cam_palm_m if raw is not None else _NAN3.copy(),
            raw_R_cam_palm=raw.R_cam_palm if raw is not None else _NAN33.copy(),
            raw_openness=raw.openness if raw is not None else _NAN5.copy(),
            width_px=frame.width_px,
            height_px=frame.height_px,
        )

    def close(self) -> None:
        """Release the detector (MediaPipe graph)."""
        if self._detector is not None:
            self._detector.close()
            self._detector = None

    def __enter__(self) -> HandTracker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def iter_frames(source: FrameSource, prefetch: int = 0) -> Generator[Frame, None, None]:
    """Every frame of a source, opening it first and closing it at the end.

    Args:
        source: any hand source (not yet opened).
        prefetch: frames decoded ahead in a reader thread (0: read in the caller's thread).
            For files read as fast as possible this overlaps decoding with tracking; the
            order and the set of frames are the same. Live sources should not prefetch:
            queued frames go stale (use `TrackingStream`).

    Yields:
        Frames in source order.
    """
    source.open()
    if prefetch <= 0:
        try:
            while (frame := source.read()) is not None:
                yield frame
        finally:
            source.close()
        return
    q: queue.Queue[Frame | BaseException | None] = queue.Queue(maxsize=prefetch)
    stop = threading.Event()

    def reader() -> None:
        item: Frame | BaseException | None = None
        try:
            while not stop.is_set():
                item = source.read()
                while not stop.is_set():
                    try:
                        q.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if item is None:
                    return
        except BaseException as exc:  # re-raised in the consumer
            q.put(exc)

    th = threading.Thread(target=reader, name="dsteleop-prefetch", daemon=True)
    th.start()
    try:
        while True:
            item = q.get()
            if item is None:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        th.join(timeout=5.0)
        source.close()


def iter_samples(
    source: FrameSource, tracker: HandTracker, max_frames: int | None = None, prefetch: int = 0
) -> Iterator[tuple[Frame, HandSample]]:
    """Every frame of a source through the tracker, as fast as possible (headless replay).

    Opens the source, and closes it when the iteration ends or is abandoned.

    Args:
        source: any hand source (not yet opened).
        tracker: the tracker; its state carries over frames.
        max_frames: stop after this many frames (None: until the source ends).
        prefetch: frames decoded ahead in a reader thread (see `iter_frames`).

    Yields:
        (frame, sample) per frame.
    """
    frames = iter_frames(source, prefetch)
    try:
        for n, frame in enumerate(frames):
            if max_frames is not None and n >= max_frames:
                return
            yield frame, tracker.process(frame)
    finally:
        frames.close()


class TrackingStream:
    """Capture and tracking in background threads; the consumer polls `latest()`.

    Two daemon threads: capture reads the source into a one-frame slot, tracking takes the
    newest frame from it and publishes a `HandSample` into a one-sample slot. A frame
    overwritten before tracking took it counts in `dropped`. Realtime sources (cameras,
    paced files) never wait for the tracker; other sources wait for the slot to empty, so
    no frame of a file read as fast as possible is dropped.

    The stream owns the source and the tracker: `stop()` closes both.

    Args:
        source: the hand source (opened by `start()`, in the caller's thread, so that a
            camera that does not open raises there).
        tracker: the tracker (default: `HandTracker()`).
    """

    def __init__(self, source: FrameSource, tracker: HandTracker | None = None) -> None:
        self.source = source
        self.tracker = tracker or HandTracker()
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._sample: HandSample | None = None
        self._stop = threading.Event()
        self._capture_done = False
        self._done = threading.Event()
        self._threads: list[threading.Thread] = []
        self.dropped = 0
        self.captured = 0
        self.tracked = 0
        self.error: BaseException | None = None
        self._opened = False

    @property
    def started(self) -> bool:
        """The capture and tracking threads run (or ran)."""
        return bool(self._threads)

    def open(self) -> TrackingStream:
        """Open the source (a camera that does not open raises here) and load the tracker's
        model, without capturing yet: a file then starts playing at `start()`, from its first
        frame, instead of while the model loads. Idempotent; returns self."""
        if not self._opened:
            self.source.open()
            self._opened = True
            width = int(getattr(self.source, "width_px", 0) or 640)
            height = int(getattr(self.source, "height_px", 0) or 480)
            if getattr(self.source, "has_pixels", True):
                self.tracker.warm_up(width, height)
        return self

    def start(self) -> TrackingStream:
        """Open the source (if `open()` was not called) and start both threads; returns self."""
        if self._threads:
            raise RuntimeError("TrackingStream already started")
        self.open()
        self._threads = [
            threading.Thread(target=self._capture, name="dsteleop-capture", daemon=True),
            threading.Thread(target=self._track, name="dsteleop-tracking", daemon=True),
        ]
        for th in self._threads:
            th.start()
        log.info("tracking stream started on %s", self.source.describe())
        return self

    def latest(self) -> HandSample | None:
        """The newest sample (None before the first); never blocks on capture or tracking."""
        return self._sample

    def wait_for(self, seq: int, timeout_s: float) -> HandSample | None:
        """Block until a sample with `seq >= seq` exists (or the stream ends / times out)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                s = self._sample
                if s is not None and s.seq >= seq:
                    return s
                left = deadline - time.monotonic()
                if left <= 0 or self.finished:
                    return s
                self._cond.wait(left)

    @property
    def finished(self) -> bool:
        """The source ended (or failed, see `error`) and every captured frame was tracked."""
        return self._done.is_set()

    def _capture(self) -> None:
        realtime = self.source.realtime
        try:
            while not self._stop.is_set():
                frame = self.source.read()
                if frame is None:
                    break
                with self._cond:
                    if not realtime:
                        while self._frame is not None and not self._stop.is_set():
                            self._cond.wait(0.1)
                    if self._frame is not None:
                        self.dropped += 1
                    self._frame = frame
                    self.captured += 1
                    self._cond.notify_all()
        except BaseException as exc:  # reported through `error`, never lost in the thread
            self.error = exc
            log.error("capture from %s failed: %s", self.source.describe(), exc)
        finally:
            with self._cond:
                self._capture_done = True
                self._cond.notify_all()

    def _track(self) -> None:
        try:
            while True:
                with self._cond:
                    while (
                        self._frame is None and not self._capture_done and not self._stop.is_set()
                    ):
                        self._cond.wait(0.1)
                    if self._stop.is_set() or self._frame is None:
                        return
                    frame, self._frame = self._frame, None
                    self._cond.notify_all()
                # The newest sample carries its frame's pixels (for a live view's camera panel).
                sample = dataclasses.replace(self.tracker.process(frame), image=frame.image)
                with self._cond:
                    self._sample = sample
                    self.tracked += 1
                    self._cond.notify_all()
        except BaseException as exc:  # reported through `error`
            self.error = exc
            self._stop.set()
            log.error("tracking failed: %s", exc)
        finally:
            with self._cond:
                self._done.set()
                self._cond.notify_all()

    def stop(self) -> None:
        """Stop both threads, then close the source and the tracker (idempotent)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for th in self._threads:
            th.join(timeout=5.0)
            if th.is_alive():
                log.warning("thread %s did not stop within 5 s", th.name)
        self.source.close()
        self.tracker.close()

    def __enter__(self) -> TrackingStream:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
