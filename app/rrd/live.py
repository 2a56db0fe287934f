"""Logging a running loop to Rerun, from its own thread, never slowing the loop.

    dsteleop run|serve ... --rerun FILE.rrd          write while running
    dsteleop run|serve ... --rerun-connect [ADDR]    stream to a Rerun viewer the user started

`RerunLogger` is one of the loop's observers (`app.ports.Observer`): `observe` only appends
the tick's record to a bounded buffer and returns. A thread of its own wakes every
`batch_s`, takes what is there and sends it as columns (`log.log_run`, under the root
`layout.LIVE_ROOT`), with the camera frames the records carry (JPEG, at most `camera_hz`)
and their landmarks. If the logger falls behind (a slow disk, an absent or slow viewer), the
buffer keeps the newest `capacity` records and the rest are dropped, counted in `dropped`:
data is lost, never a tick. `close()` sends what is left and flushes.
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Sequence
from typing import Any

import rerun as rr

from dsteleop.app.rrd import layout
from dsteleop.app.rrd import log as rlog
from dsteleop.app.rrd.target import RerunTarget, viewer_listening
from dsteleop.app.session.schema import TickRecord
from dsteleop.robot.scene import SceneGeometry

log = logging.getLogger(__name__)

#: How long `close` waits for a `--rerun-connect` viewer to take what is left [s] (an absent
#: viewer must not hold the process).
FLUSH_TIMEOUT_S = 0.5


class RerunLogger:
    """The loop's Rerun observer (module docstring).

    Args:
        target: the file and/or viewer.
        recording_id: the recording's id (the session's name, or the run's start time).
        scene: the plant's scene (shapes logged once; poses per tick when the plant exports
            them), or None.
        plant_meta: the plant's description (its true goals), or None.
        batch_s: how often the thread sends what arrived [s].
        capacity: records kept while the thread is behind (older ones are dropped).
        camera_hz: at most this many camera frames a second are encoded and sent.
    """

    def __init__(
        self,
        target: RerunTarget,
        recording_id: str,
        scene: SceneGeometry | None = None,
        plant_meta: dict[str, Any] | None = None,
        batch_s: float = 0.5,
        capacity: int = 900,
        camera_hz: float = 10.0,
    ) -> None:
        self.target = target
        self.scene = scene
        self.batch_s = batch_s
        self.camera_hz = camera_hz
        self.received = 0
        self.dropped = 0
        self.logged = 0
        self._buf: collections.deque[TickRecord] = collections.deque(maxlen=capacity)
        self._cond = threading.Condition()
        self._stop = False
        self._t0: float | None = None
        self._last_frame_t = -1e9
        self.rec = rr.RecordingStream(layout.APPLICATION_ID, recording_id=recording_id)
        if target.path is not None:
            self.rec.save(target.path)
        #: Whether a viewer listened at `--rerun-connect`'s address when the run started
        #: (None: no address).
        self.viewer_reachable: bool | None = None
        if target.connect is not None:
            self.viewer_reachable = viewer_listening(target.connect)
            if not self.viewer_reachable:
                log.warning(
                    "--rerun-connect: no Rerun viewer listens at %s (start `rerun` first); "
                    "what this run sends is kept in memory and lost at the end unless one starts",
                    target.connect,
                )
            # Rerun's client sends from its own thread and buffers while no viewer is there;
            # `close` waits for it at most FLUSH_TIMEOUT_S.
            self.rec.connect_grpc(target.connect)
        self.rec.send_blueprint(rlog.blueprint([layout.LIVE_ROOT], camera=True))
        if scene is not None:
            rlog.log_scene_geometry(self.rec, layout.LIVE_ROOT, scene)
        if plant_meta is not None:
            rlog.log_true_goals(self.rec, plant_meta)
        self._thread = threading.Thread(target=self._run, name="rerun-logger", daemon=True)
        self._thread.start()

    # --- the loop's side ----------------------------------------------------------------

    def observe(self, record: TickRecord) -> None:
        """Called from the loop's thread: append and return."""
        with self._cond:
            if len(self._buf) == self._buf.maxlen:
                self.dropped += 1
            self._buf.append(record)
            self.received += 1

    # --- the logger's thread ------------------------------------------------------------

    def _take(self) -> list[TickRecord]:
        with self._cond:
            batch = list(self._buf)
            self._buf.clear()
        return batch

    def _run(self) -> None:
        while True:
            with self._cond:
                if not self._stop:
                    self._cond.wait(self.batch_s)
                stopping = self._stop
            batch = self._take()
            if batch:
                try:
                    self._send(batch)
                except Exception:  # a logger must never take the loop down
                    log.exception("rerun logging failed; dropping %d records", len(batch))
                    self.dropped += len(batch)
            if stopping:
                return

    def _send(self, batch: Sequence[TickRecord]) -> None:
        if self._t0 is None:
            self._t0 = batch[0].t_s
        t0 = self._t0
        rlog.log_run(self.rec, layout.LIVE_ROOT, batch, t0, self.scene)
        rlog.log_camera(self.rec, self._frames(batch, t0))
        rlog.log_landmarks(self.rec, batch, t0)
        self.logged += len(batch)

    def _frames(self, batch: Sequence[TickRecord], t0: float) -> list[rlog.CameraFrame]:
        import cv2

        out, seen = [], set()
        for r in batch:
            s = r.hand.sample if r.hand is not None else None
            img = None if s is None else s.image
            if img is None or s is None or s.seq in seen:
                continue
            seen.add(s.seq)
            if s.t_capture_s - self._last_frame_t < 1.0 / self.camera_hz:
                continue
            self._last_frame_t = s.t_capture_s
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
            if ok:
                out.append(rlog.CameraFrame(s.t_capture_s - t0, buf.tobytes()))
        return out

    def summary(self) -> dict[str, Any]:
        """What a command's summary says about the recording: where it went, ticks logged
        and dropped, and whether a viewer listened at `--rerun-connect`'s address (at the
        start, and now)."""
        out: dict[str, Any] = {
            "file": None if self.target.path is None else str(self.target.path),
            "connect": self.target.connect,
            "ticks_logged": self.logged,
            "ticks_dropped": self.dropped,
        }
        if self.target.connect is not None:
            now = viewer_listening(self.target.connect)
            out["viewer_reachable"] = bool(self.viewer_reachable or now)
            if not out["viewer_reachable"]:
                out["note"] = "no viewer listened: the logged ticks reached no one"
        return out

    def close(self) -> dict[str, int]:
        """Send what is left, flush, stop the thread; the counts (received, logged, dropped)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout=30.0)
        try:
            if self.target.connect is None:
                self.rec.flush()
            else:
                try:
                    self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
                except Exception as e:  # Rerun raises on the timeout; its type is not public
                    log.warning("rerun: the viewer did not take everything in time (%s)", e)
        finally:
            self.rec.disconnect()
        stats = {"received": self.received, "logged": self.logged, "dropped": self.dropped}
        log.info("rerun: %s", stats)
        return stats
