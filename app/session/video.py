"""Records the camera frames of a session beside it, crash-safe, for `replay --retrack`.

`FrameRecorder` wraps a frame source: while a recording is active, every frame that has
pixels goes to a writer thread, which appends it to `SESSION/video.mp4` and then its line to
`SESSION/frames.jsonl` (`{"i", "seq", "t_capture"}`: its index in the video, the source's
frame number, its capture time on the loop's clock), flushed per frame. A re-tracked replay
reads the video's frames in order and gives frame `i` the capture time of line `i`, so it
sees the same frames at the same times as the live loop.

Crash safety: `video.mp4` is a *fragmented* MP4 (H.264), written by `Mp4Writer` with every
frame in its own fragment and the file flushed after each: a process killed at any moment
(even `kill -9`) leaves a video that players and OpenCV read up to the last frame written,
and every line of `frames.jsonl` names a frame that is in the video (a line is written once
its frame is in the file). An ordinary MP4 is unreadable until its index is written at
close ("moov atom not found"), which is why OpenCV's VideoWriter is not used here: it passes
no options to the MP4 muxer, and its Matroska keeps about half a second of frames in memory
(measured: 15-20 frames lost to `kill -9`). PyAV (FFmpeg's libraries) writes the fragments;
reading stays with OpenCV (`tracking.sources`).
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
from fractions import Fraction
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import InputError
from dsteleop.tracking.sources import FrameSource
from dsteleop.tracking.types import Frame

log = logging.getLogger(__name__)

VIDEO = "video.mp4"
FRAMES = "frames.jsonl"
#: Every frame its own fragment, an empty index up front, each packet flushed to the file.
MP4_OPTIONS = {
    "movflags": "frag_keyframe+empty_moov+default_base_moof+frag_every_frame",
    "flush_packets": "1",
}


#: Niceness added to the video writer's thread: encoding is background work.
WRITER_NICENESS = 10


def lower_thread_priority(niceness: int = WRITER_NICENESS) -> None:
    """Lower the calling thread's CPU priority by `niceness` (Linux: per thread; elsewhere,
    or when not allowed, nothing happens)."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + niceness)
    except (AttributeError, OSError):
        pass


class EncodedVideo:
    """One video stream in an open container: frames are stamped with their index, encoded
    and muxed; `close` drains the encoder and finishes the file. Subclasses open `_out` and
    `_stream` and set `frames = 0`."""

    _out: Any
    _stream: Any
    frames: int

    def _encode(self, frame: Any) -> None:
        """Stamp `frame` (an av.VideoFrame) as the next frame, encode it, mux its packets."""
        frame.pts = self.frames
        for packet in self._stream.encode(frame):
            self._out.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Drain the encoder and finish the file (idempotent)."""
        if self._out is None:
            return
        try:
            for packet in self._stream.encode(None):
                self._out.mux(packet)
        finally:
            self._out.close()
            self._out = None


class Mp4Writer(EncodedVideo):
    """BGR frames to a fragmented, crash-safe MP4 (module docstring).

    H.264 (libx264, `ultrafast`, `zerolatency`: no frame is held back in the encoder) at
    constant quality `crf`, one keyframe a second; MPEG-4 part 2 where the FFmpeg build has no
    libx264. Frames are stamped at the constant rate `fps` (their real capture times belong
    in an index beside the video). Odd sizes lose their last row or column (4:2:0 chroma).

    Args:
        path: the file (created or replaced).
        fps: frame rate [Hz] of the stamps.
        width_px, height_px: size of the frames written.
        crf: H.264 constant rate factor (lower: better and larger; 18-23 look alike).

    Raises:
        InputError: the file cannot be created.
    """

    def __init__(
        self, path: Path, fps: float, width_px: int, height_px: int, crf: int = 20
    ) -> None:
        import av

        self.path = Path(path)
        self.width_px, self.height_px = width_px - width_px % 2, height_px - height_px % 2
        rate = Fraction(fps).limit_denominator(1001)
        try:
            self._out: Any = av.open(str(self.path), "w", format="mp4", options=MP4_OPTIONS)
        except (OSError, av.FFmpegError) as exc:
            raise InputError(f"cannot write a video at {self.path}: {exc}") from exc
        if "libx264" in av.codecs_available:
            stream: Any = self._out.add_stream("libx264", rate=rate)
            stream.options = {
                "preset": "ultrafast",
                "tune": "zerolatency",
                "crf": str(crf),
                "threads": "1",  # one core's slice at 30 fps; more threads only compete
            }
        else:
            stream = self._out.add_stream("mpeg4", rate=rate)
            stream.bit_rate = 4_000_000
        stream.width, stream.height = self.width_px, self.height_px
        stream.pix_fmt = "yuv420p"
        stream.codec_context.gop_size = max(1, round(fps))
        self._stream = stream
        self._av = av
        self.frames = 0

    def write(self, image_bgr: NDArray[np.uint8]) -> None:
        """Append one frame (H x W x 3, BGR; the size given at construction)."""
        image = image_bgr[: self.height_px, : self.width_px]
        self._encode(self._av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24"))


class FrameRecorder:
    """A frame source that copies its frames into the active session (module docstring).

    Args:
        source: the wrapped source.
        fps: frame rate written into the video's stamps [Hz] (default: the source's).
    """

    def __init__(self, source: FrameSource, fps: float | None = None) -> None:
        # FFmpeg's libraries load now, before the loop runs: importing them takes ~0.1 s
        # holding the interpreter, which the first recorded frame would otherwise take from
        # the loop (measured: a tick started 200 ms late).
        import av  # noqa: F401

        self.source = source
        self._fps = fps
        self.fps = fps or source.fps
        self.realtime = source.realtime
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue[Frame | None] | None = None
        self._thread: threading.Thread | None = None
        self._folder: Path | None = None
        self.written = 0

    def describe(self) -> str:
        return self.source.describe()

    def open(self) -> None:
        self.source.open()
        self.fps = self._fps or self.source.fps  # a video knows its rate once open

    def close(self) -> None:
        self.stop()
        self.source.close()

    def start(self, folder: Path) -> None:
        """Begin writing frames into `folder` (a session folder)."""
        with self._lock:
            self._stop_locked()
            self._folder = Path(folder)
            self._folder.mkdir(parents=True, exist_ok=True)
            q: queue.SimpleQueue[Frame | None] = queue.SimpleQueue()
            self._queue = q
            self._thread = threading.Thread(
                target=self._write, args=(self._folder, q), name="dsteleop-video", daemon=True
            )
            self._thread.start()

    def stop(self) -> None:
        """Write what is queued, then close the video and its index."""
        with self._lock:
            self._stop_locked()

    def _stop_locked(self) -> None:
        if self._queue is not None and self._thread is not None:
            self._queue.put(None)
            self._thread.join()
        self._queue = None
        self._thread = None
        self._folder = None

    def read(self) -> Frame | None:
        frame = self.source.read()
        if frame is not None and frame.image is not None:
            with self._lock:
                if self._queue is not None:
                    self._queue.put(frame)
        return frame

    def _write(self, folder: Path, q: queue.SimpleQueue[Frame | None]) -> None:
        """The writer thread: frames in order into the video, and each one's index line
        once the frame is in the file. The MP4 muxer writes a frame's fragment when the next
        frame arrives (that one's time closes it), so a line follows one frame behind; the
        last is written after the video is closed. The thread (and the encoder it runs)
        yields the CPU to the control loop: it runs at a lower priority (niceness +10)."""
        lower_thread_priority()
        writer: Mp4Writer | None = None
        index: IO[str] | None = None
        pending: str | None = None
        try:
            while (frame := q.get()) is not None:
                image = frame.image
                if image is None:
                    continue
                if writer is None:
                    w, h = image.shape[1], image.shape[0]
                    writer = Mp4Writer(folder / VIDEO, float(self.fps or 30.0), w, h)
                    index = open(folder / FRAMES, "a", encoding="utf-8")  # noqa: SIM115
                assert index is not None
                row = {"i": writer.frames, "seq": frame.seq, "t_capture": frame.t_capture_s}
                writer.write(image)
                if pending is not None:
                    index.write(pending)
                    index.flush()
                pending = json.dumps(row) + "\n"
                self.written += 1
        except Exception as exc:  # the session's ticks go on; its video stops here
            log.error("recording the camera frames into %s stopped: %s", folder, exc)
            while q.get() is not None:  # keep the producer from queueing forever
                pass
        finally:
            if writer is not None:
                writer.close()
            if index is not None:
                if pending is not None:
                    index.write(pending)
                index.close()
