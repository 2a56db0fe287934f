"""Records the camera frames of a session beside it, for `dsteleop replay --retrack`.

`FrameRecorder` wraps a frame source: while a recording is active it writes every frame that has
pixels to `SESSION/video.mp4` and its sequence number and capture time to
`SESSION/frames.jsonl` (flushed per frame), so a re-tracked replay sees the same frames at the
same times on the loop's clock.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import IO, Any

from dsteleop.tracking.sources import FrameSource
from dsteleop.tracking.types import Frame

VIDEO = "video.mp4"
FRAMES = "frames.jsonl"


class FrameRecorder:
    """A frame source that copies its frames into the active session (see module docstring).

    Args:
        source: the wrapped source.
        fps: frame rate written into the video's header [Hz].
    """

    def __init__(self, source: FrameSource, fps: float = 30.0) -> None:
        self.source = source
        self.fps = fps
        self.realtime = source.realtime
        self._lock = threading.Lock()
        self._writer: Any = None
        self._index: IO[str] | None = None
        self._folder: Path | None = None

    def describe(self) -> str:
        return self.source.describe()

    def open(self) -> None:
        self.source.open()

    def close(self) -> None:
        self.stop()
        self.source.close()

    def start(self, folder: Path) -> None:
        """Begin writing frames into `folder` (a session folder)."""
        with self._lock:
            self._stop_locked()
            self._folder = Path(folder)
            self._folder.mkdir(parents=True, exist_ok=True)
            self._index = open(self._folder / FRAMES, "a", encoding="utf-8")  # noqa: SIM115

    def stop(self) -> None:
        with self._lock:
            self._stop_locked()

    def _stop_locked(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._index is not None:
            self._index.close()
            self._index = None
        self._folder = None

    def read(self) -> Frame | None:
        frame = self.source.read()
        if frame is None or frame.image is None:
            return frame
        with self._lock:
            if self._index is not None and self._folder is not None:
                if self._writer is None:
                    import cv2

                    h, w = frame.image.shape[:2]
                    fourcc = cv2.VideoWriter.fourcc(*"mp4v")
                    self._writer = cv2.VideoWriter(
                        str(self._folder / VIDEO), fourcc, self.fps, (w, h)
                    )
                self._writer.write(frame.image)
                self._index.write(
                    json.dumps({"seq": frame.seq, "t_capture": frame.t_capture_s}) + "\n"
                )
                self._index.flush()
        return frame
