"""`--record-video`: the camera's frames beside each session, as a crash-safe MP4 and a
frame index (`session.video.FrameRecorder`), for `replay --retrack` and datasets."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from dsteleop.app import sources
from dsteleop.app.outputs import OutputBase, OutputContext, OutputKind
from dsteleop.errors import ConfigError

if TYPE_CHECKING:
    from dsteleop.app.session.video import FrameRecorder
    from dsteleop.tracking.sources import FrameSource, SourceSpec

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--record-video",
        action="store_true",
        help="also record the camera frames (for replay --retrack)",
    )


def parse(args: argparse.Namespace, source: SourceSpec) -> bool | None:
    """True when asked for; a source without pixels is refused (the demo's synthetic hand,
    an input that is not a camera)."""
    if not args.record_video:
        return None
    if not sources.kind(source.kind).pixels:
        raise ConfigError(
            f"--record-video: --source {source} has no camera frames to record (no pixels); "
            "record a webcam or a video source, or leave --record-video out"
        )
    return True


class VideoOutput(OutputBase):
    """Records the hand's frames into each session (`wrap_source` puts the recorder in the
    frames' way; the hand closes it with its source)."""

    def __init__(self) -> None:
        self.recorder: FrameRecorder | None = None

    def wrap_source(self, source: FrameSource) -> FrameSource:
        from dsteleop.app.session.video import FrameRecorder

        self.recorder = FrameRecorder(source)
        return self.recorder

    def start_session(self, folder: Path) -> None:
        if self.recorder is not None:
            self.recorder.start(folder)

    def stop_session(self) -> None:
        if self.recorder is not None:
            self.recorder.stop()


def open_output(setting: bool, ctx: OutputContext) -> VideoOutput | None:
    if not ctx.pixels:
        log.warning("--record-video: the source has no camera frames; no video is recorded")
        return None
    return VideoOutput()


KIND = OutputKind("video", add_arguments, parse, open_output)
