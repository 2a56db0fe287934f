"""The camera of a dataset: a session's frames picked per tick, re-encoded as LeRobot does.

Each tick gets the newest frame captured at or before the tick's start (the image the
operator's hand was tracked from by then; the first frame for ticks before any), read from
the session's `video.mp4` in order with the capture times of `frames.jsonl`. The frames are
re-encoded into the dataset's video with one of the format's codecs: by default H.264 (x264
at its fastest preset, yuv420p, a keyframe every 2 frames, CRF 30: LeRobot's settings with
its `h264` codec), or with `--codec av1` LeRobot's own default (SVT-AV1, the same keyframe
interval, pixel format and CRF, preset 12; `DEFAULT_CODEC` says why not by default), one
frame per tick stamped
frame / fps, so LeRobot's reader finds frame k of an episode at `from_timestamp + k / fps`.
Decoded frames go to the encoder as they are (already yuv420p): no colour conversion, except
for the frames sampled for the statistics.
"""

from __future__ import annotations

import bisect
import logging
import os
from collections.abc import Iterator, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.session.video import EncodedVideo
from dsteleop.errors import InputError

log = logging.getLogger(__name__)

#: LeRobot's default video encoder (lerobot.configs.video.VideoEncoderConfig).
SVTAV1 = {"vcodec": "libsvtav1", "pix_fmt": "yuv420p", "g": 2, "crf": 30, "preset": 12}
#: Its settings for H.264 (a codec LeRobot also reads), x264's fastest preset.
H264 = {"vcodec": "libx264", "pix_fmt": "yuv420p", "g": 2, "crf": 30, "preset": "ultrafast"}


#: The camera's codec unless asked otherwise: H.264. SVT-AV1 at LeRobot's settings encodes
#: ~140 frames/s of 852x480 on two cores (its fastest preset), under 5x real time at 30 Hz
#: before anything else is done, and it takes both cores from a live loop (`--record-lerobot`);
#: x264 ultrafast encodes ~900 frames/s. LeRobot reads both; `--codec av1` gives its own.
DEFAULT_CODEC = "h264"


def frames_for_ticks(frame_t_s: Sequence[float], tick_t_s: Sequence[float]) -> list[int]:
    """For each tick, the index of the newest frame captured at or before it (0 before any)."""
    return [max(0, bisect.bisect_right(frame_t_s, t + 1e-9) - 1) for t in tick_t_s]


class SessionFrames:
    """A session's recorded frames, read forward once (episodes in order).

    Args:
        video: the session's video.mp4.
        frame_t_s: the capture time of each frame (frames.jsonl), in video order.

    Raises:
        InputError: the video cannot be opened or holds no frame.
    """

    def __init__(self, video: Path, frame_t_s: Sequence[float]) -> None:
        import av

        try:
            self._in: Any = av.open(str(video))
            stream = self._in.streams.video[0]
        except (OSError, IndexError, av.FFmpegError) as exc:
            raise InputError(f"{video}: unreadable video ({exc})") from None
        stream.thread_type = "AUTO"
        self.video = video
        self.width, self.height = int(stream.width), int(stream.height)
        self._frames: Iterator[Any] = self._in.decode(stream)
        self._index = -1
        self._frame: Any = None
        self.times = list(frame_t_s)

    def frame(self, i: int) -> Any:
        """Frame `i` (an av.VideoFrame); `i` never below the last asked for. A video shorter
        than its index gives its last frame."""
        import av

        while self._index < i:
            try:
                self._frame = next(self._frames)
            except StopIteration:
                break
            except av.FFmpegError as exc:
                raise InputError(f"{self.video}: corrupt video ({exc})") from None
            self._index += 1
        if self._frame is None:
            raise InputError(f"{self.video}: no frame in the video")
        return self._frame

    def close(self) -> None:
        self._in.close()


class CameraEncoder(EncodedVideo):
    """Writes the dataset's camera video: frames in, one per tick (module docstring).

    Args:
        path: the .mp4 to write.
        fps: the dataset's frame rate [Hz].
        width, height: the frames' size (others are scaled to it).
        codec: "h264" (the default, `DEFAULT_CODEC`) or "av1" (LeRobot's own default; H.264
            where this FFmpeg has no SVT-AV1); LeRobot reads both.
    """

    def __init__(
        self, path: Path, fps: int, width: int, height: int, codec: str = DEFAULT_CODEC
    ) -> None:
        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1's banner and notices: errors only
        import av

        av1 = codec == "av1" and "libsvtav1" in av.codecs_available
        self.settings = dict(SVTAV1 if av1 else H264)
        self.path = Path(path)
        self.fps = fps
        self.width, self.height = width - width % 2, height - height % 2
        self._out: Any = av.open(str(self.path), "w", format="mp4")
        s = self.settings
        options = {"g": str(s["g"]), "crf": str(s["crf"]), "preset": str(s["preset"])}
        if s["vcodec"] == "libsvtav1":
            options["svtav1-params"] = "fast-decode=0"
        stream: Any = self._out.add_stream(str(s["vcodec"]), rate=fps, options=options)
        stream.width, stream.height, stream.pix_fmt = self.width, self.height, s["pix_fmt"]
        stream.time_base = Fraction(1, fps)
        self._stream = stream
        self.frames = 0

    def write(self, frame: Any) -> None:
        """Append one decoded frame (an av.VideoFrame) as the next tick's."""
        if (
            frame.width != self.width
            or frame.height != self.height
            or frame.format.name != (self.settings["pix_fmt"])
        ):
            frame = frame.reformat(self.width, self.height, self.settings["pix_fmt"])
        # The encoder takes a reference to the frame as it is sent: a frame repeated for the
        # next tick is sent again with its next stamp.
        frame.time_base = Fraction(1, self.fps)
        self._encode(frame)

    def info(self) -> dict[str, Any]:
        """The `info` block of the camera's feature in info.json (LeRobot's `get_video_info`
        and the encoder settings)."""
        s = self.settings
        return {
            "video.height": self.height,
            "video.width": self.width,
            "video.codec": "av1" if s["vcodec"] == "libsvtav1" else "h264",
            "video.pix_fmt": s["pix_fmt"],
            "video.fps": self.fps,
            "video.channels": 3,
            "video.g": s["g"],
            "video.crf": s["crf"],
            "video.preset": s["preset"],
            "video.fast_decode": 0,
            "video.extra_options": {},
            "video.video_backend": "pyav",
            "has_audio": False,
            "is_depth_map": False,
        }


def rgb(frame: Any, max_side: int = 300, target: int = 150) -> NDArray[np.uint8]:
    """A frame as RGB (H, W, 3) for the statistics, reduced as LeRobot's statistics reduce
    frames of `max_side` pixels or more (by the whole factor that brings the longer side
    near `target`; scaled by FFmpeg here rather than strided)."""
    h, w = frame.height, frame.width
    if max(h, w) >= max_side:
        step = int(max(h, w) / target)
        a: NDArray[np.uint8] = frame.reformat(w // step, h // step, "rgb24").to_ndarray()
        return a
    out: NDArray[np.uint8] = frame.to_ndarray(format="rgb24")
    return out
