"""Hand sources: a webcam, a video file, a folder of images, the synthetic operator.

They all satisfy `FrameSource`: `open()`, `read() -> Frame | None` (None at the end),
`close()`, `describe()`, and the attributes `fps` and `realtime`. A realtime source delivers
frames at its own pace and stamps them with `time.monotonic()`; the others are read as fast
as the consumer asks and stamp frames with their own clock (frame index / fps), so replay is
deterministic. `TrackingStream` (pipeline.py) runs any source in a capture thread.

Every bad input becomes a one-line `DsteleopError`: a missing, unreadable, corrupt or empty
file, an empty folder, a camera that does not open (with the cameras that do).
"""

from __future__ import annotations

import glob
import importlib
import logging
import math
import sys
import time
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dsteleop.errors import DsteleopError
from dsteleop.tracking.pose import CameraIntrinsics
from dsteleop.tracking.synthetic import LandmarkNoise, SyntheticSource, scripted_trajectory
from dsteleop.tracking.types import Frame, Image

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff")
#: Camera indices probed when listing the cameras that open (no /dev/video* to look at).
_PROBE_INDICES = range(6)


class FrameSource(Protocol):
    """One interface for every hand source (module docstring)."""

    fps: float
    realtime: bool

    def open(self) -> None: ...

    def read(self) -> Frame | None: ...

    def close(self) -> None: ...

    def describe(self) -> str: ...


def _cv2() -> Any:
    """OpenCV, imported on first use (never at import time of this package)."""
    return importlib.import_module("cv2")


def _resize(image: Image, size: tuple[int, int] | None) -> Image:
    if size is None or (image.shape[1], image.shape[0]) == size:
        return image
    out: Image = _cv2().resize(image, size, interpolation=_cv2().INTER_AREA)
    return out


class VideoFileSource:
    """A video file OpenCV can read.

    Args:
        path: the file.
        realtime: pace frames at the file's fps on the monotonic clock; frames the consumer
            is too slow for are dropped by the stream (newest wins). False: every frame as
            fast as the consumer reads, stamped seq / fps.
        size: resize frames to (width, height) [px] on read (None: as stored).
        loop: start again at the end (realtime demos).

    Attributes:
        skipped: frames a realtime reader skipped because they were already overdue.
        width_px, height_px: size of the stored frames (after `open()`).
        frame_count: frames the container reports (after `open()`; may be approximate).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        realtime: bool = False,
        size: tuple[int, int] | None = None,
        loop: bool = False,
    ) -> None:
        self.path = Path(path)
        self.realtime = realtime
        self.size = size
        self.loop = loop
        self.fps = 30.0
        self.frame_count = 0
        self.width_px = 0
        self.height_px = 0
        self.skipped = 0
        self._cap: Any = None
        self._seq = 0
        self._index = 0
        self._t0 = 0.0

    def describe(self) -> str:
        return f"video {self.path}"

    def open(self) -> None:
        """Open and check the file (raises DsteleopError with one line on bad input)."""
        cv2 = _cv2()
        if not self.path.exists():
            raise DsteleopError(f"video not found: {self.path}")
        if not self.path.is_file():
            raise DsteleopError(f"not a file: {self.path}")
        if self.path.stat().st_size == 0:
            raise DsteleopError(f"video is empty (0 bytes): {self.path}")
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise DsteleopError(f"cannot read video (corrupt or unsupported format): {self.path}")
        ok, first = cap.read()
        if not ok or first is None:
            cap.release()
            raise DsteleopError(f"video has no readable frames: {self.path}")
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        self.fps = fps if math.isfinite(fps) and 1.0 <= fps <= 1000.0 else 30.0
        self.frame_count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.height_px, self.width_px = first.shape[:2]
        cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self._cap = cap
        self._seq = 0
        self._index = 0
        self._t0 = time.monotonic()
        log.info(
            "video %s: %d frames at %.3g fps, %dx%d",
            self.path,
            self.frame_count,
            self.fps,
            first.shape[1],
            first.shape[0],
        )

    def read(self) -> Frame | None:
        """The next frame, or None at the end of the file."""
        if self._cap is None:
            raise RuntimeError("VideoFileSource.read() before open()")
        if self.realtime:
            # Pace on the file's clock; the stream's one slot drops what the consumer misses,
            # and frames already overdue by a whole period are skipped without decoding.
            delay = self._t0 + self._index / self.fps - time.monotonic()
            while delay < -1.0 / self.fps and self._cap.grab():
                self._index += 1
                self.skipped += 1
                delay += 1.0 / self.fps
            if delay > 0:
                time.sleep(delay)
        ok, image = self._cap.read()
        if not ok or image is None:
            if not self.loop or self._index == 0:
                return None
            self._cap.set(_cv2().CAP_PROP_POS_FRAMES, 0)
            ok, image = self._cap.read()
            if not ok:
                return None
        image = _resize(image, self.size)
        t = time.monotonic() if self.realtime else self._seq / self.fps
        frame = Frame(self._seq, t, image.shape[1], image.shape[0], image=image)
        self._seq += 1
        self._index += 1
        return frame

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def available_cameras() -> list[str]:
    """Cameras that open: /dev/video* device paths on Linux, else probed indices.

    On Linux a machine without /dev/video* has no camera, so nothing is probed; OpenCV's own
    log is silenced while probing (its failed opens are expected, not errors).
    """
    cv2 = _cv2()
    devices = sorted(glob.glob("/dev/video*"))
    if not devices and sys.platform.startswith("linux"):
        return []
    candidates: list[str | int] = list(devices) if devices else list(_PROBE_INDICES)
    found = []
    level = cv2.getLogLevel()
    cv2.setLogLevel(0)  # silent
    try:
        for cand in candidates:
            cap = cv2.VideoCapture(cand)
            try:
                if cap.isOpened():
                    found.append(str(cand))
            finally:
                cap.release()
    finally:
        cv2.setLogLevel(level)
    return found


class WebcamSource:
    """A live camera by index (0, 1, ...) or device path (/dev/video0).

    Args:
        device: index or path.
        size: requested (width, height) [px]; the camera may pick the nearest it has.
        fps: requested frame rate [Hz].
    """

    realtime = True

    def __init__(
        self, device: int | str, *, size: tuple[int, int] | None = (640, 480), fps: float = 30.0
    ) -> None:
        self.device = device
        self.size = size
        self.fps = fps
        self._cap: Any = None
        self._seq = 0

    def describe(self) -> str:
        return f"camera {self.device}"

    def open(self) -> None:
        """Open the camera (DsteleopError listing the cameras that open, if it does not)."""
        cv2 = _cv2()
        level = cv2.getLogLevel()
        cv2.setLogLevel(0)  # a camera that does not open gets our one line, not OpenCV's
        try:
            cap = cv2.VideoCapture(self.device)
        finally:
            cv2.setLogLevel(level)
        if not cap.isOpened():
            cap.release()
            found = available_cameras()
            listing = ", ".join(found) if found else "none"
            raise DsteleopError(
                f"camera {self.device} does not open (cameras that open: {listing})"
            )
        if self.size is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[1])
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # newest frame, not a backlog
        reported = float(cap.get(cv2.CAP_PROP_FPS))
        if math.isfinite(reported) and reported > 0:
            self.fps = reported
        self._cap = cap
        self._seq = 0

    def read(self) -> Frame | None:
        """Block until the next frame; None if the camera stops delivering."""
        if self._cap is None:
            raise RuntimeError("WebcamSource.read() before open()")
        ok, image = self._cap.read()
        t = time.monotonic()
        if not ok or image is None:
            log.warning("camera %s stopped delivering frames", self.device)
            return None
        frame = Frame(self._seq, t, image.shape[1], image.shape[0], image=image)
        self._seq += 1
        return frame

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class ImageFolderSource:
    """The images of a folder in name order, as frames at `fps`.

    Args:
        path: the folder.
        fps: clock of the frames [Hz] (t = seq / fps).
        size: resize to (width, height) [px] (None: as stored).
        realtime: pace at `fps` on the monotonic clock.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        fps: float = 30.0,
        size: tuple[int, int] | None = None,
        realtime: bool = False,
    ) -> None:
        self.path = Path(path)
        self.fps = fps
        self.size = size
        self.realtime = realtime
        self.files: list[Path] = []
        self._seq = 0
        self._t0 = 0.0

    def describe(self) -> str:
        return f"images in {self.path} ({len(self.files)})"

    def open(self) -> None:
        """List the images (DsteleopError if the folder is missing or holds none)."""
        if not self.path.is_dir():
            raise DsteleopError(f"image folder not found: {self.path}")
        self.files = sorted(
            p for p in self.path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
        )
        if not self.files:
            raise DsteleopError(
                f"no images in {self.path} (looked for {', '.join(IMAGE_SUFFIXES)})"
            )
        self._seq = 0
        self._t0 = time.monotonic()

    def read(self) -> Frame | None:
        """The next image, or None after the last (DsteleopError on an unreadable file)."""
        if self._seq >= len(self.files):
            return None
        path = self.files[self._seq]
        if self.realtime:
            delay = self._t0 + self._seq / self.fps - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        image = _cv2().imread(str(path), _cv2().IMREAD_COLOR)
        if image is None or image.size == 0:
            raise DsteleopError(f"cannot read image (corrupt or unsupported): {path}")
        image = _resize(np.ascontiguousarray(image), self.size)
        t = time.monotonic() if self.realtime else self._seq / self.fps
        frame = Frame(self._seq, t, image.shape[1], image.shape[0], image=image)
        self._seq += 1
        return frame

    def close(self) -> None:
        return None


def open_source(
    spec: str,
    *,
    realtime: bool = False,
    size: tuple[int, int] | None = None,
    fps: float = 30.0,
    duration_s: float | None = None,
) -> FrameSource:
    """Build (not open) the source a command-line SOURCE names.

    Args:
        spec: "synthetic" (the scripted synthetic operator), a camera index ("0") or device
            path ("/dev/video0"), a folder of images, or a video file.
        realtime: pace files at their fps (cameras are always live).
        size: resize frames to (width, height) [px]; for cameras, the requested size.
        fps: frame rate of image folders and the synthetic operator [Hz].
        duration_s: length of the synthetic operator's run [s] (default 10 s).
    """
    if spec == "synthetic":
        w, h = size or (640, 480)
        return SyntheticSource(
            scripted_trajectory(),
            fps=fps,
            duration_s=10.0 if duration_s is None else duration_s,
            camera=CameraIntrinsics.from_hfov(w, h, 60.0),
            noise=LandmarkNoise(image_px=1.0, world_m=0.002),
            realtime=realtime,
        )
    if spec.isdigit():
        return WebcamSource(int(spec), size=size or (640, 480), fps=fps)
    if spec.startswith("/dev/video"):
        return WebcamSource(spec, size=size or (640, 480), fps=fps)
    path = Path(spec)
    if path.is_dir():
        return ImageFolderSource(path, fps=fps, size=size, realtime=realtime)
    if not path.exists():
        raise DsteleopError(
            f"source not found: {spec} "
            "(give a video file, an image folder, a camera index or 'synthetic')"
        )
    return VideoFileSource(path, realtime=realtime, size=size)
