"""The tracking sources (`tracking.sources`): a webcam, a video file, a folder of images, the
scripted synthetic hand; their frames go through the tracking pipeline."""

from __future__ import annotations

from pathlib import Path

from dsteleop.app.sources import Opened, SourceContext, SourceKind
from dsteleop.tracking.sources import SourceSpec, VideoFileSource, open_source


def open_camera(spec: SourceSpec, ctx: SourceContext) -> Opened:
    source = open_source(spec, realtime=ctx.realtime, rotate=ctx.rotate, loop=ctx.loop_video)
    return Opened(frames=source, video=source if isinstance(source, VideoFileSource) else None)


def _file(spec: SourceSpec) -> str:
    return f"{spec.kind} {Path(spec.target).name or spec.target}"


KINDS = (
    SourceKind(
        "webcam",
        "webcam:N (or webcam:/dev/videoN, or N)",
        open_camera,
        target=True,
        pixels=True,
        live=True,
        label=lambda spec: f"camera {spec.target}",
        tracked=True,
    ),
    SourceKind(
        "video",
        "video:PATH (or a video file)",
        open_camera,
        target=True,
        pixels=True,
        label=_file,
        tracked=True,
    ),
    SourceKind(
        "images",
        "images:DIR (or a folder of images)",
        open_camera,
        target=True,
        pixels=True,
        label=_file,
        tracked=True,
    ),
    # Landmarks drawn from a hand model: no pixels (no video to record).
    SourceKind(
        "synthetic", "synthetic", open_camera, label=lambda spec: "synthetic hand", tracked=True
    ),
)
