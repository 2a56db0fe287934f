"""`dsteleop serve`: the live session with its browser view.

    dsteleop serve [--source webcam:0 | video:PATH | demo] [--mode DS]
                   [--host 127.0.0.1] [--port 8080] [--record DIR] [loop options]

Without `--source` the first webcam is used when one opens, otherwise the built-in demo (a
synthetic operator doing the pick-and-place task), and a line says so. The view listens on
127.0.0.1 (this machine only) unless `--host` says otherwise; `--host 0.0.0.0` logs that
anyone who can reach the port can steer the robot. A port in use is one clear error naming
the port (exit code 2), checked before the camera is opened.

Trials follow one another: the task resets `--reset-after` seconds (default 4) after each
outcome, and a trial without one after `--time-limit` seconds fails (`timeout`); each is an
episode of the recording. `--record DIR` records from the first tick into a new folder
`DIR/<date>-<time>-<mode>-<utensil>/`; the page's Recording Start writes there too
(without `--record`: under `default_record_root()`, the user's data folder, never the
current one). A video source plays from the loop's first tick and the page says when it
ended (`--loop-video` plays it again).

The loop runs in the main thread at its fixed rate; the viewer has its own thread and reads
the loop's tick records through a one-slot subscription. Ctrl-C (SIGINT) and SIGTERM stop the
loop at the end of its tick; then the view is stopped, the recording closed (complete) and
the camera released, in `finally`. When it stops, the command prints one JSON object with
the loop's timing summary on stdout.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app import sources
from dsteleop.app.cli.options import add_loop_options, check_video_complete, loop_options
from dsteleop.app.cli.signals import StopOnSignal
from dsteleop.app.compose.options import RESET_AFTER_S, LoopOptions
from dsteleop.app.outputs import session_root
from dsteleop.errors import ConfigError

log = logging.getLogger(__name__)

ALL_INTERFACES = ("0.0.0.0", "::", "")


def default_record_root() -> Path:
    """Where the page's Recording Start writes without --record: `dsteleop/sessions` in the
    user's data folder (`$XDG_DATA_HOME`, else `~/.local/share`), an absolute path, so that
    a session never lands in whatever folder `serve` was started from (nor among the
    repository's sample sessions in recordings/)."""
    base = os.environ.get("XDG_DATA_HOME") or ""
    root = Path(base) if base and Path(base).is_absolute() else Path.home() / ".local" / "share"
    return root / "dsteleop" / "sessions"


@dataclass(frozen=True)
class ServeCommand:
    """The `serve` command's settings (logged at start).

    Attributes:
        options: the loop options shared with `run` (`--record DIR`: record the session
            into a new folder under DIR from the start; the page's recordings go there too).
        host: address the view listens on.
        port: TCP port of the view (0: any free port).
    """

    options: LoopOptions
    host: str
    port: int


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_loop_options(
        parser,
        default_source="auto",
        record_help="record from the start, each session in a new folder "
        "DIR/<date>-<time>-<mode>-<utensil>/; the page's Recording Start writes there too "
        "(default: $XDG_DATA_HOME/dsteleop/sessions, else ~/.local/share/dsteleop/sessions)",
    )
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only)",
    )
    parser.add_argument("--port", type=int, default=8080, help="port of the view (default 8080)")


def command(args: argparse.Namespace) -> ServeCommand:
    options = loop_options(args, reset_after_s=RESET_AFTER_S)
    if not 0 <= int(args.port) <= 65535:
        raise ConfigError(f"--port must be in 0..65535, got {args.port}")
    return ServeCommand(options, str(args.host), int(args.port))


def run(args: argparse.Namespace) -> int:
    cmd = command(args)
    opts = cmd.options
    log.info(
        "serve: source %s, mode %s, host %s, port %d, record %s",
        opts.source, opts.loop.mode.value, cmd.host, cmd.port, opts.record,
    )  # fmt: skip
    from dsteleop.app.compose.root import build, hand_mapping
    from dsteleop.app.loop.timing import raise_priority
    from dsteleop.app.session.writer import new_session_folder
    from dsteleop.app.viewer.panel import source_label
    from dsteleop.app.viewer.server import Viewer, ViewerConfig, check_port_free, sliders_for

    if cmd.host in ALL_INTERFACES:
        log.warning(
            "listening on all interfaces (%s): anyone who can reach port %d can steer the robot",
            cmd.host or "*",
            cmd.port,
        )
    check_port_free(cmd.host, cmd.port)  # before the camera is opened
    raise_priority()  # the loop ahead of other work on the machine (a local browser)
    # Sessions go under --record; else where an output that needs them says (a dataset's
    # sessions), recorded from the start; else the page's recordings go to the data folder.
    needed = session_root(opts.outputs)
    root = opts.record or needed or default_record_root()
    built = build(opts, realtime=True, export_scene=True, record_root=root)
    loop, spec = built.loop, built.source
    plant = loop.task.describe()
    info = sources.kind(spec.kind).info()
    if info is not None and opts.change_mind is not None:
        info = {**info, "person": "turns to the {} after {:g} s".format(*opts.change_mind)}
    viewer = None
    # Signals stop the loop from here on, also while closing: a second Ctrl-C during the
    # cleanup must not cut the recording's close short.
    with StopOnSignal(loop) as stopper:
        try:
            viewer = Viewer(
                loop.broadcaster,
                loop.controls,
                scene=loop.task.scene(),
                config=ViewerConfig(host=cmd.host, port=cmd.port),
                utensils=tuple(plant.get("goals") or plant.get("utensils") or ()),
                utensil=plant.get("goal"),
                sliders=sliders_for(
                    loop.config.arbitration, loop.task.describe().get("goal_noise_m", 0.0)
                ),
                arbitration=loop.config.arbitration,
                source=source_label(spec),
                mapping=hand_mapping(loop.hand.mapping_config()),
                info=info,
            )
            if opts.record is not None or needed is not None:
                utensil = str(loop.task.describe().get("utensil", "task"))
                loop.start_recording(new_session_folder(root, loop.mode.value, utensil))
            viewer.start()
            sys.stderr.write(
                f"dsteleop serve: open {viewer.url} in a browser "
                f"(source {spec}, mode {loop.mode.value}); Ctrl-C stops\n"
            )
            sys.stderr.flush()
            loop.run()
        finally:
            if viewer is not None:
                viewer.close()
            built.close()  # the recording (complete), the camera, the robot, the Rerun log
    recordings = [str(f) for f in loop.recordings]
    summary: dict[str, Any] = {
        "source": str(spec),
        "stopped_by": stopper.received or "end of run",
        # The last session recorded (from --record or the page), and all of them.
        "recording": recordings[-1] if recordings else None,
        "recordings": recordings,
        "timing": loop.timing_summary(),
        # The page's Stop presses (each latched until Resume), and whether it ended stopped.
        "operator_stops": loop.stops,
        "ended_stopped": loop.stopped,
    }
    summary.update(built.summaries())  # what each output wrote, by its name
    if built.video is not None:
        summary["video"] = built.video.end_note() if built.video.ended else "playing"
    sys.stdout.write(json.dumps(summary) + "\n")
    if built.video is not None:
        check_video_complete(built.video, opts.allow_partial, "the session was served")
    return 0
