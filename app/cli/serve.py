"""`dsteleop serve`: the live session with its browser view.

    dsteleop serve [--source webcam:0 | video:PATH | demo] [--mode DS]
                   [--host 127.0.0.1] [--port 8080] [--record DIR] [loop options]

Without `--source` the first webcam is used when one opens, otherwise the built-in demo (a
synthetic operator doing the pick-and-place task), and a line says so. The view listens on
127.0.0.1 (this machine only) unless `--host` says otherwise; `--host 0.0.0.0` logs that
anyone who can reach the port can steer the robot. A port in use is one clear error naming
the port (exit code 2), checked before the camera is opened.

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
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from dsteleop.app.cli.options import LoopOptions, add_loop_options, loop_options
from dsteleop.app.cli.signals import StopOnSignal
from dsteleop.errors import ConfigError

if TYPE_CHECKING:
    from dsteleop.app.loop import TeleopLoop

log = logging.getLogger(__name__)

ALL_INTERFACES = ("0.0.0.0", "::", "")
DEFAULT_RECORD_ROOT = Path("recordings")  # where "Start recording" writes without --record


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
    add_loop_options(parser, default_source="auto")
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only)",
    )
    parser.add_argument("--port", type=int, default=8080, help="port of the view (default 8080)")


def command(args: argparse.Namespace) -> ServeCommand:
    options = loop_options(args)
    if not 0 <= int(args.port) <= 65535:
        raise ConfigError(f"--port must be in 0..65535, got {args.port}")
    return ServeCommand(options, str(args.host), int(args.port))


class DemoRestarter:
    """Keeps the demo going: a few seconds after each outcome, the operator and the task
    restart (through `Controls`, like the GUI's reset button).

    Args:
        loop: the running loop (its broadcaster and controls are used).
        stop: set to end the thread.
        delay_s: pause after an outcome before the restart [s].
    """

    def __init__(self, loop: TeleopLoop, stop: threading.Event, delay_s: float = 4.0) -> None:
        self._loop = loop
        self._stop = stop
        self._delay_s = delay_s

    def start(self) -> None:
        threading.Thread(target=self._run, name="dsteleop-demo-restart", daemon=True).start()

    def _run(self) -> None:
        sub = self._loop.broadcaster.subscribe()
        t_outcome: float | None = None
        try:
            while not self._stop.is_set():
                snap = sub.wait(0.5)
                if snap is None:
                    continue
                now = time.monotonic()
                if not snap.outcome:
                    t_outcome = None
                elif t_outcome is None:
                    t_outcome = now
                elif now - t_outcome >= self._delay_s:
                    # A task reset restarts the demo operator too (it sees the reset in
                    # the next record), and re-anchors the mapping on the first fresh hand.
                    self._loop.controls.reset()
                    t_outcome = None
                    self._stop.wait(1.0)
        finally:
            sub.close()


def run(args: argparse.Namespace) -> int:
    cmd = command(args)
    opts = cmd.options
    log.info(
        "serve: source %s, mode %s, host %s, port %d, record %s",
        opts.source, opts.loop.mode.value, cmd.host, cmd.port, opts.record,
    )  # fmt: skip
    from dsteleop.app.cli.compose import build
    from dsteleop.app.loop.timing import raise_priority
    from dsteleop.app.session.writer import new_session_folder
    from dsteleop.app.viewer.server import Viewer, ViewerConfig, check_port_free, sliders_for

    if cmd.host in ALL_INTERFACES:
        log.warning(
            "listening on all interfaces (%s): anyone who can reach port %d can steer the robot",
            cmd.host or "*",
            cmd.port,
        )
    check_port_free(cmd.host, cmd.port)  # before the camera is opened
    raise_priority()  # the loop ahead of other work on the machine (a local browser)
    root = opts.record or DEFAULT_RECORD_ROOT
    built = build(opts, realtime=True, export_scene=True, history_dir=opts.record, record_root=root)
    loop, spec = built.loop, built.source
    viewer = None
    stop_demo = threading.Event()
    # Signals stop the loop from here on, also while closing: a second Ctrl-C during the
    # cleanup must not cut the recording's close short.
    with StopOnSignal(loop) as stopper:
        try:
            viewer = Viewer(
                loop.broadcaster,
                loop.controls,
                scene=loop.plant.scene(),
                config=ViewerConfig(host=cmd.host, port=cmd.port),
                utensils=tuple(loop.plant.describe().get("utensils", ())),
                sliders=sliders_for(
                    loop.config.arbitration, loop.plant.describe().get("goal_noise_m", 0.0)
                ),
            )
            if opts.record is not None:
                utensil = str(loop.plant.describe().get("utensil", "task"))
                loop.start_recording(new_session_folder(opts.record, loop.mode.value, utensil))
            viewer.start()
            if built.demo is not None:
                DemoRestarter(loop, stop_demo).start()
            sys.stderr.write(
                f"dsteleop serve: open {viewer.url} in a browser "
                f"(source {spec}, mode {loop.mode.value}); Ctrl-C stops\n"
            )
            sys.stderr.flush()
            loop.run()
        finally:
            stop_demo.set()
            if viewer is not None:
                viewer.close()
            recording = loop.recording
            built.close()  # the recording (complete), the camera, the robot, the Rerun log
    summary = {
        "source": str(spec),
        "stopped_by": stopper.received or "end of run",
        "recording": None if recording is None else str(recording),
        "timing": loop.rate.summary(),
    }
    sys.stdout.write(json.dumps(summary) + "\n")
    return 0
