"""`dsteleop serve`: the live session with its browser view.

    dsteleop serve [--source webcam:0 | video:PATH | demo] [--mode DS]
                   [--host 127.0.0.1] [--port 8080] [--record DIR]

Without `--source` the first webcam is used when one opens, otherwise the built-in demo (a
synthetic operator doing the pick-and-place task), and a line says so. The view listens on
127.0.0.1 (this machine only) unless `--host` says otherwise; `--host 0.0.0.0` logs that
anyone who can reach the port can steer the robot. A port in use is one clear error naming
the port (exit code 2), checked before the camera is opened.

The loop runs in the main thread at its fixed rate; the viewer has its own thread and reads
the loop's snapshots through a one-slot subscription. Ctrl-C (SIGINT) and SIGTERM stop the
loop at the end of its tick; then the view is stopped, the recording closed (complete) and
the camera released, in `finally`. When it stops, the command prints one JSON object with
the loop's timing summary on stdout.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import logging
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from dsteleop.app.timing import raise_priority
from dsteleop.app.viewer import DEFAULT_SLIDERS, Slider, Viewer, ViewerConfig, check_port_free
from dsteleop.arbitration import Mode
from dsteleop.errors import DsteleopError

log = logging.getLogger(__name__)

ALL_INTERFACES = ("0.0.0.0", "::", "")
DEFAULT_RECORD_ROOT = Path("recordings")  # where "Start recording" writes without --record


@dataclass(frozen=True)
class ServeCommand:
    """The `serve` command's settings (logged at start).

    Attributes:
        source: "webcam:N", "video:PATH" or "demo"; None: a webcam if one opens, else demo.
        mode: arbitration mode at start.
        host: address the view listens on.
        port: TCP port of the view (0: any free port).
        record: record the session into a new folder under this directory, or None.
    """

    source: str | None
    mode: Mode
    host: str
    port: int
    record: Path | None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--source",
        default=None,
        help="webcam:N, video:PATH or demo (default: the first webcam, else the demo)",
    )
    parser.add_argument(
        "--mode",
        default="DS",
        help="arbitration mode at start: DS, S, manual or autonomous (default DS)",
    )
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only)",
    )
    parser.add_argument("--port", type=int, default=8080, help="port of the view (default 8080)")
    parser.add_argument(
        "--record", type=Path, default=None, metavar="DIR", help="record the session under DIR"
    )


def _command(args: argparse.Namespace) -> ServeCommand:
    try:
        mode = Mode.parse(str(args.mode))
    except ValueError as exc:
        raise DsteleopError(str(exc)) from exc
    if not 0 <= int(args.port) <= 65535:
        raise DsteleopError(f"--port must be in 0..65535, got {args.port}")
    source = args.source
    if source is not None:
        kind = source.split(":", 1)[0]
        if kind not in ("webcam", "video", "demo", "auto"):
            raise DsteleopError(f"--source must be webcam:N, video:PATH or demo, got {source!r}")
    return ServeCommand(source, mode, str(args.host), int(args.port), args.record)


def open_loop(cmd: ServeCommand) -> tuple[Any, Any, str]:
    """Build the live loop (`dsteleop.app.setup`) for the command's source.

    Without a source: the first webcam that opens, otherwise the demo, with a line saying
    so (`setup.resolve_source("auto")`).

    Returns:
        (loop, demo operator or None, the source spec used).
    """
    from dsteleop.app.loop import LoopConfig
    from dsteleop.app.setup import Setup, build, resolve_source

    spec = resolve_source(cmd.source or "auto")  # logs when it falls back to the demo
    setup = Setup(
        source=spec,
        loop=LoopConfig(mode=cmd.mode),
        realtime=True,
        export_scene=True,
        history_dir=cmd.record,
    )
    built = build(setup)
    return built.loop, built.demo, spec


class DemoRestarter:
    """Keeps the demo going: a few seconds after each outcome, the operator and the task
    restart (through `Controls`, like the GUI's reset button).

    Args:
        loop: the running loop (its broadcaster and controls are used).
        demo: the demo operator (`setup.Built.demo`).
        stop: set to end the thread.
        delay_s: pause after an outcome before the restart [s].
    """

    def __init__(self, loop: Any, demo: Any, stop: threading.Event, delay_s: float = 4.0) -> None:
        self._loop = loop
        self._demo = demo
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
                    # A task reset restarts the demo operator too (`loop.on_task_reset`),
                    # and re-anchors the mapping on the first fresh hand.
                    self._loop.controls.reset()
                    t_outcome = None
                    self._stop.wait(1.0)
        finally:
            sub.close()


def _new_session_folder(root: Path) -> Path:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    folder = root / f"session-{stamp}"
    k = 1
    while folder.exists():
        k += 1
        folder = root / f"session-{stamp}-{k}"
    return folder


class _StopOnSignal:
    """SIGINT/SIGTERM stop the loop at the end of its tick (main thread only)."""

    def __init__(self, loop: Any) -> None:
        self._loop = loop
        self._old: dict[int, Any] = {}
        self.received: str | None = None

    def __enter__(self) -> _StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        self.received = signal.Signals(signum).name
        self._loop.stop()

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


def _sliders(loop: Any) -> tuple[Slider, ...]:
    """The GUI sliders, starting at the loop's current values."""
    arb = loop.config.arbitration
    noise = loop.plant.describe().get("goal_noise_m", 0.0)
    now = {
        "kappa": arb.kappa,
        "p": arb.p,
        "q": arb.q,
        "b": arb.b,
        "window": arb.window,
        "goal_noise_m": noise,
    }
    out = []
    for s in DEFAULT_SLIDERS:
        v = float(now.get(s.name, s.initial))
        out.append(dataclasses.replace(s, initial=min(max(v, s.low), s.high)))
    return tuple(out)


def run(args: argparse.Namespace) -> int:
    cmd = _command(args)
    log.info("serve: %s", {k: getattr(v, "value", str(v)) for k, v in asdict(cmd).items()})
    if cmd.host in ALL_INTERFACES:
        log.warning(
            "listening on all interfaces (%s): anyone who can reach port %d can steer the robot",
            cmd.host or "*",
            cmd.port,
        )
    check_port_free(cmd.host, cmd.port)  # before the camera is opened
    raise_priority()  # the loop ahead of other work on the machine (a local browser)
    loop, demo, spec = open_loop(cmd)
    viewer = None
    stop_demo = threading.Event()
    # Signals stop the loop from here on, also while closing: a second Ctrl-C during the
    # cleanup must not cut the recording's close short.
    with _StopOnSignal(loop) as stopper:
        try:
            # "Start recording" in the page records a new trial under this folder.
            loop.record_root = cmd.record or DEFAULT_RECORD_ROOT
            viewer = Viewer(
                loop.broadcaster,
                loop.controls,
                scene=loop.plant.scene_description(),
                config=ViewerConfig(host=cmd.host, port=cmd.port),
                utensils=tuple(loop.plant.describe().get("utensils", ())),
                sliders=_sliders(loop),
            )
            if cmd.record is not None:
                loop.start_recording(_new_session_folder(cmd.record))
            viewer.start()
            if demo is not None:
                DemoRestarter(loop, demo, stop_demo).start()
            sys.stderr.write(
                f"dsteleop serve: open {viewer.url} in a browser "
                f"(source {spec}, mode {cmd.mode.value}); Ctrl-C stops\n"
            )
            sys.stderr.flush()
            loop.run()
        finally:
            stop_demo.set()
            if viewer is not None:
                viewer.close()
            recording = getattr(loop, "recording", None)
            loop.close()  # closes the recording (complete), releases the camera and robot
    summary = {
        "source": spec,
        "stopped_by": stopper.received or "end of run",
        "recording": None if recording is None else str(recording),
        "timing": loop.rate.summary(),
    }
    sys.stdout.write(json.dumps(summary) + "\n")
    return 0
