"""Hand sources: a webcam, a video file, a folder of images, the synthetic operator.

They all satisfy `FrameSource`: `open()`, `read() -> Frame | None` (None at the end),
`close()`, `describe()`, and the attributes `fps` and `realtime`. A realtime source delivers
frames at its own pace and stamps them with `time.monotonic()`; the others are read as fast
as the consumer asks and stamp frames with their own clock (frame index / fps), so replay is
deterministic. `TrackingStream` (pipeline.py) runs any source in a capture thread.

Every bad input becomes a one-line `InputError`: a missing, unreadable, corrupt or empty
file, an empty folder, a camera that does not open (with the cameras that do).
"""

from __future__ import annotations

import contextlib
import glob
import importlib
import logging
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dsteleop.errors import ConfigError, InputError
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


#: Rotations a video's frames can be turned by [deg, clockwise] (`--rotate`).
ROTATIONS_DEG = (0, 90, 180, 270)
#: A video may decode a little fewer frames than its container declares (edit lists, counts
#: rounded from the duration): it is complete if it is short by at most this many frames ...
PARTIAL_SLACK_FRAMES = 2
#: ... or this fraction of the declared count, whichever is larger.
PARTIAL_SLACK_FRACTION = 0.01


def check_rotation(deg: int | None) -> int | None:
    """A `--rotate` value, checked (None: the container's own rotation).

    Raises:
        ConfigError: not one of `ROTATIONS_DEG`.
    """
    if deg is None:
        return None
    if isinstance(deg, bool) or deg not in ROTATIONS_DEG:
        raise ConfigError(f"--rotate must be one of 0, 90, 180, 270 (degrees), got {deg!r}")
    return int(deg)


def _rotate(image: Image, deg: int) -> Image:
    """`image` turned `deg` degrees clockwise (0, 90, 180, 270)."""
    if deg == 0:
        return image
    cv2 = _cv2()
    code = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}
    out: Image = cv2.rotate(image, code[deg])
    return out


class VideoFileSource:
    """A video file OpenCV can read, turned upright as a player shows it.

    Phone videos often store their frames sideways and say in the container (a display
    matrix) how to turn them for display. The source reads that rotation with OpenCV
    (`CAP_PROP_ORIENTATION_META`) and turns every frame itself (`CAP_PROP_ORIENTATION_AUTO` is
    switched off, so that no OpenCV build turns it twice); `rotate` overrides the container.
    Image up is then the person's up, which the workspace mapping turns into robot up.

    A file that ends before the frame count its container declares (a truncated download, an
    unreadable tail) is `partial`; `check_complete()` says so in one line.

    Args:
        path: the file.
        realtime: pace frames at the file's fps on the monotonic clock, from the first
            `read()` (so a live loop that starts later sees the clip from its first frame);
            frames the consumer is too slow for are dropped by the stream (newest wins).
            False: every frame as fast as the consumer reads, stamped seq / fps.
        size: resize the upright frames to (width, height) [px] on read (None: as stored).
        loop: start again at the end (`--loop-video`).
        rotate: turn the stored frames this many degrees clockwise (0, 90, 180, 270)
            instead of what the container says (None: the container's rotation).

    Attributes:
        skipped: frames a realtime reader skipped because they were already overdue.
        width_px, height_px: size of the upright frames before `size` (after `open()`).
        frame_count: frames the container declares (after `open()`; may be approximate).
        frames_read: frames decoded (or skipped as overdue) on the first pass through the file.
        rotation_deg: the rotation applied [deg, clockwise] (after `open()`).
        container_rotation_deg: the rotation the container asks for (after `open()`).
        ended: the first pass reached the end of the readable frames.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        realtime: bool = False,
        size: tuple[int, int] | None = None,
        loop: bool = False,
        rotate: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.realtime = realtime
        self.size = size
        self.loop = loop
        self.rotate = check_rotation(rotate)
        self.fps = 30.0
        self.frame_count = 0
        self.frames_read = 0
        self.width_px = 0
        self.height_px = 0
        self.rotation_deg = 0
        self.container_rotation_deg = 0
        self.skipped = 0
        self.ended = False
        self._cap: Any = None
        self._seq = 0
        self._index = 0
        self._t0: float | None = None

    def describe(self) -> str:
        return f"video {self.path}"

    def open(self) -> None:
        """Open and check the file (raises InputError with one line on bad input)."""
        cv2 = _cv2()
        if not self.path.exists():
            raise InputError(f"video not found: {self.path}")
        if not self.path.is_file():
            raise InputError(f"not a file: {self.path}")
        if self.path.stat().st_size == 0:
            raise InputError(f"video is empty (0 bytes): {self.path}")
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise InputError(f"cannot read video (corrupt or unsupported format): {self.path}")
        cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)  # we turn the frames (class docstring)
        ok, first = cap.read()
        if not ok or first is None:
            cap.release()
            raise InputError(f"video has no readable frames: {self.path}")
        meta = float(cap.get(cv2.CAP_PROP_ORIENTATION_META))
        self.container_rotation_deg = round(meta / 90.0) * 90 % 360 if math.isfinite(meta) else 0
        self.rotation_deg = self.container_rotation_deg if self.rotate is None else self.rotate
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        self.fps = fps if math.isfinite(fps) and 1.0 <= fps <= 1000.0 else 30.0
        self.frame_count = max(0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT)))
        self.height_px, self.width_px = _rotate(first, self.rotation_deg).shape[:2]
        cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
        self._cap = cap
        self._seq = 0
        self._index = 0
        self.frames_read = 0
        self.ended = False
        self._t0 = None
        log.info(
            "video %s: %d frames at %.3g fps, stored %dx%d, turned %d deg clockwise (%s)",
            self.path,
            self.frame_count,
            self.fps,
            first.shape[1],
            first.shape[0],
            self.rotation_deg,
            "the container's rotation" if self.rotate is None else "--rotate",
        )

    @property
    def partial(self) -> bool:
        """The first pass ended short of the declared frame count (module constants say by
        how much a complete file may be short)."""
        slack = max(PARTIAL_SLACK_FRAMES, math.ceil(PARTIAL_SLACK_FRACTION * self.frame_count))
        return self.ended and self.frames_read < self.frame_count - slack

    def end_note(self) -> str:
        """How much of the file was read, in words (for logs and the view)."""
        return f"read {self.frames_read} of the {self.frame_count} frames it declares"

    def check_complete(self) -> None:
        """Raise if the file turned out `partial`.

        Raises:
            InputError: one line with the counts.
        """
        if self.partial:
            raise InputError(
                f"{self.path}: {self.end_note()} (truncated or partly unreadable); "
                "--allow-partial accepts it"
            )

    def _grab(self) -> bool:
        ok = bool(self._cap.grab())
        if ok and not self.ended:
            self.frames_read += 1
        return ok

    def read(self) -> Frame | None:
        """The next upright frame, or None at the end of the file."""
        if self._cap is None:
            raise RuntimeError("VideoFileSource.read() before open()")
        if self.realtime:
            # Pace on the file's clock from the first read; the stream's one slot drops what
            # the consumer misses, and frames already overdue by a whole period are skipped
            # without decoding.
            now = time.monotonic()
            if self._t0 is None:
                self._t0 = now - self._index / self.fps
            delay = self._t0 + self._index / self.fps - now
            while delay < -1.0 / self.fps and self._grab():
                self._index += 1
                self.skipped += 1
                delay += 1.0 / self.fps
            if delay > 0:
                time.sleep(delay)
        image = self._decode()
        if image is None:
            if not self.ended:
                self.ended = True
                log.info("video %s ended: %s", self.path, self.end_note())
            if not self.loop or self._index == 0:
                return None
            self._cap.set(_cv2().CAP_PROP_POS_FRAMES, 0)
            self._t0 = None if self.realtime else self._t0
            self._index = 0
            image = self._decode()
            if image is None:
                return None
        image = _resize(_rotate(image, self.rotation_deg), self.size)
        t = time.monotonic() if self.realtime else self._seq / self.fps
        frame = Frame(self._seq, t, image.shape[1], image.shape[0], image=image)
        self._seq += 1
        self._index += 1
        return frame

    def _decode(self) -> Image | None:
        if not self._grab():
            return None
        ok, image = self._cap.retrieve()
        return image if ok and image is not None else None

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
    with _opencv_silent(cv2):
        for cand in candidates:
            cap = cv2.VideoCapture(cand)
            try:
                if cap.isOpened():
                    found.append(str(cand))
            finally:
                cap.release()
    return found


@contextlib.contextmanager
def _opencv_silent(cv2: Any) -> Iterator[None]:
    """OpenCV's own log silenced inside (`cv2.utils.logging`, in OpenCV 4 and 5 alike; OpenCV
    5 has no top-level `cv2.setLogLevel`): failed camera opens are ours to report."""
    log = cv2.utils.logging
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        log.setLogLevel(level)


class WebcamSource:
    """A live camera by index (0, 1, ...) or device path (/dev/video0).

    Args:
        device: index or path.
        size: requested (width, height) [px]; the camera may pick the nearest it has.
        fps: requested frame rate [Hz].
        rotate: turn every frame this many degrees clockwise (a camera mounted sideways).
    """

    realtime = True

    def __init__(
        self,
        device: int | str,
        *,
        size: tuple[int, int] | None = (640, 480),
        fps: float = 30.0,
        rotate: int | None = None,
    ) -> None:
        self.device = device
        self.size = size
        self.fps = fps
        self.rotation_deg = check_rotation(rotate) or 0
        self._cap: Any = None
        self._seq = 0

    def describe(self) -> str:
        return f"camera {self.device}"

    def open(self) -> None:
        """Open the camera (InputError listing the cameras that open, if it does not)."""
        cv2 = _cv2()
        with _opencv_silent(cv2):  # a camera that does not open gets our one line
            cap = cv2.VideoCapture(self.device)
        if not cap.isOpened():
            cap.release()
            found = available_cameras()
            listing = ", ".join(found) if found else "none"
            raise InputError(f"camera {self.device} does not open (cameras that open: {listing})")
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
        image = _rotate(image, self.rotation_deg)
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
        """List the images (InputError if the folder is missing or holds none)."""
        if not self.path.is_dir():
            raise InputError(f"image folder not found: {self.path}")
        self.files = sorted(
            p for p in self.path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
        )
        if not self.files:
            raise InputError(f"no images in {self.path} (looked for {', '.join(IMAGE_SUFFIXES)})")
        self._seq = 0
        self._t0 = time.monotonic()

    def read(self) -> Frame | None:
        """The next image, or None after the last (InputError on an unreadable file)."""
        if self._seq >= len(self.files):
            return None
        path = self.files[self._seq]
        if self.realtime:
            delay = self._t0 + self._seq / self.fps - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        image = _cv2().imread(str(path), _cv2().IMREAD_COLOR)
        if image is None or image.size == 0:
            raise InputError(f"cannot read image (corrupt or unsupported): {path}")
        image = _resize(np.ascontiguousarray(image), self.size)
        t = time.monotonic() if self.realtime else self._seq / self.fps
        frame = Frame(self._seq, t, image.shape[1], image.shape[0], image=image)
        self._seq += 1
        return frame

    def close(self) -> None:
        return None


#: The tracking package's sources: webcam, video, images, synthetic (the app adds its own,
#: `app.sources`: the demo, auto).
SOURCE_GRAMMAR = (
    "webcam:N (or webcam:/dev/videoN, or N), video:PATH (or a video file), "
    "images:DIR (or a folder of images), or synthetic"
)


@dataclass(frozen=True)
class SourceSpec:
    """A parsed `--source` (the one grammar of every command that reads a hand).

    Attributes:
        kind: `webcam`, `video`, `images` (a folder of stills), `synthetic` (the scripted
            synthetic hand), or a source the app registers (`app.sources`: the demo, auto).
        target: the camera index or device path, or the file or folder path; "" otherwise.
    """

    kind: str
    target: str = ""

    def __str__(self) -> str:
        return f"{self.kind}:{self.target}" if self.target else self.kind


def parse_source(text: str, grammar: str = SOURCE_GRAMMAR) -> SourceSpec:
    """Parse a tracking `--source` value (`SOURCE_GRAMMAR`); a bare path or index is told by
    its type. `grammar` is the grammar the errors cite (the app's has more sources).

    Raises:
        ConfigError: an unknown kind, or a kind without its target.
    """
    text = str(text).strip()
    if not text:
        raise ConfigError(f"--source is empty ({grammar})")
    if text == "synthetic":
        return SourceSpec(text)
    if text in ("webcam", "video", "images"):
        raise ConfigError(f"--source {text}: needs a target, e.g. {text}:... ({grammar})")
    kind, sep, target = text.partition(":")
    if sep and kind in ("webcam", "video", "images"):
        if not target:
            raise ConfigError(f"--source {kind}: needs a target ({grammar})")
        return SourceSpec(kind, target)
    if sep and kind == "synthetic":
        raise ConfigError(f"--source {kind} takes no target, got {text!r}")
    if sep and len(kind) > 1 and not Path(text).exists():
        raise ConfigError(f"unknown source kind {kind!r} in {text!r} ({grammar})")
    if text.isdigit() or text.startswith("/dev/video"):
        return SourceSpec("webcam", text)
    if Path(text).is_dir():
        return SourceSpec("images", text)
    return SourceSpec("video", text)  # a file; whether it exists is `open_source`'s to say


def open_source(
    spec: SourceSpec | str,
    *,
    realtime: bool = False,
    size: tuple[int, int] | None = None,
    fps: float = 30.0,
    duration_s: float | None = None,
    rotate: int | None = None,
    loop: bool = False,
) -> FrameSource:
    """Build (not open) the frame source of a tracking `--source` (`TRACKING_KINDS`; the
    app's own sources, the demo and auto, are `app.sources`').

    Args:
        spec: the source, parsed or as text.
        realtime: pace files at their fps (cameras are always live).
        size: resize frames to (width, height) [px]; for cameras, the requested size.
        fps: frame rate of image folders and the synthetic operator [Hz].
        duration_s: length of the synthetic operator's run [s] (default 10 s).
        rotate: turn video and camera frames this many degrees clockwise (None: a video's
            own rotation, a camera's frames as they come).
        loop: play a video again from the start when it ends.

    Raises:
        InputError: a file or folder that does not exist.
        ConfigError: a kind that is not a tracking source.
    """
    spec = parse_source(spec) if isinstance(spec, str) else spec
    if spec.kind == "synthetic":
        w, h = size or (640, 480)
        return SyntheticSource(
            scripted_trajectory(),
            fps=fps,
            duration_s=10.0 if duration_s is None else duration_s,
            camera=CameraIntrinsics.from_hfov(w, h, 60.0),
            noise=LandmarkNoise(image_px=1.0, world_m=0.002),
            realtime=realtime,
        )
    if spec.kind == "webcam":
        device: int | str = int(spec.target) if spec.target.isdigit() else spec.target
        return WebcamSource(device, size=size or (640, 480), fps=fps, rotate=rotate)
    if spec.kind == "images":
        return ImageFolderSource(Path(spec.target), fps=fps, size=size, realtime=realtime)
    if spec.kind == "video":
        path = Path(spec.target)
        if not path.exists():
            raise InputError(f"video not found: {path} (a source is {SOURCE_GRAMMAR})")
        return VideoFileSource(path, realtime=realtime, size=size, loop=loop, rotate=rotate)
    raise ConfigError(f"--source {spec.kind} is not a tracking source here")
