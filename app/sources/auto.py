"""`--source auto` (serve's default): the first camera that opens, otherwise the demo, with a
line saying so; resolved when the loop is built, never opened itself."""

from __future__ import annotations

import logging

from dsteleop.app.sources import Opened, SourceContext, SourceKind
from dsteleop.errors import ConfigError
from dsteleop.tracking.sources import SourceSpec, available_cameras

log = logging.getLogger(__name__)


def resolve(spec: SourceSpec) -> SourceSpec:
    cams = available_cameras()
    if cams:
        return SourceSpec("webcam", cams[0])
    log.info("no webcam opens: starting the built-in demo (synthetic operator)")
    return SourceSpec("demo")


def open_auto(spec: SourceSpec, ctx: SourceContext) -> Opened:
    raise ConfigError("--source auto: resolved to a camera or the demo before it is opened")


KIND = SourceKind("auto", "auto", open_auto, pixels=True, live=True, resolve=resolve)
