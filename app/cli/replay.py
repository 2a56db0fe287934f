"""`dsteleop replay SESSION... --modes S,DS --out DIR`: headless replay and metrics.

Each session (or folder of sessions, or video file) is replayed in every requested mode
(`app/replay/core.py` says how), and DIR gets `metrics.json` (per session and mode, then
aggregated over sessions with the paper's tests) and PNG plots; one JSON line on stdout.

    --robot simulated    a fresh PyBullet robot per mode (the default): where each mode
                         would have taken the robot
    --robot recorded     the robot the session recorded, open loop: the recorded mode gives
                         back the recorded arbitration exactly; another mode, what it would
                         have computed along the same robot path
    --as-recorded        the sessions' own ticks, as they happened
    --retrack            re-run tracking on each session's video first
    --rerun FILE.rrd     also write a Rerun recording: one per session, every replayed mode
                         on one timeline (docs/recordings.md)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from dsteleop.app.cli.options import add_config_options, arbitration_config
from dsteleop.app.cli.progress import Progress, prepare_out_dir
from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import ConfigError, InputError

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v"}


@dataclass(frozen=True)
class ReplayCommand:
    """The `replay` command's settings.

    Attributes:
        inputs: session folders and video files, in order.
        modes: the modes to replay in.
        out: the output folder.
        robot: replay against a "simulated" or the "recorded" robot.
        as_recorded: metrics of the sessions as they happened instead.
        retrack: re-track each session's video.
        workers: processes.
        plots: write the PNG plots.
        arbitration: hyper-parameters for the replays (None: each session's own).
        rerun: write a Rerun recording of every run to this .rrd file, or None.
    """

    inputs: tuple[Path, ...]
    modes: tuple[Mode, ...]
    out: Path
    robot: Literal["simulated", "recorded"]
    as_recorded: bool
    retrack: bool
    workers: int
    plots: bool
    arbitration: ArbitrationConfig | None
    rerun: Path | None = None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="SESSION",
        help="session folders, folders of sessions, or video files",
    )
    parser.add_argument(
        "--modes", default="S,DS", help="comma-separated modes to replay in (default S,DS)"
    )
    parser.add_argument(
        "--out", required=True, type=Path, help="output folder for metrics.json and plots"
    )
    parser.add_argument(
        "--robot",
        choices=("simulated", "recorded"),
        default="simulated",
        help="replay against a fresh simulated robot (default) or the recorded one",
    )
    parser.add_argument(
        "--as-recorded", action="store_true", help="metrics of the sessions as they happened"
    )
    parser.add_argument(
        "--retrack", action="store_true", help="re-run tracking on each session's video"
    )
    parser.add_argument(
        "--workers", type=int, default=min(2, os.cpu_count() or 1), help="parallel processes"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument(
        "--rerun",
        type=Path,
        default=None,
        metavar="FILE.rrd",
        help="also write a Rerun recording of every session and mode (open with: rerun FILE.rrd)",
    )
    add_config_options(parser)


def _expand(inputs: list[str]) -> tuple[Path, ...]:
    from dsteleop.app.session.reader import is_session

    out: list[Path] = []
    for s in inputs:
        p = Path(s)
        if not p.exists():
            raise InputError(f"not found: {p}")
        if p.is_dir() and not is_session(p):
            subs = sorted(q for q in p.iterdir() if q.is_dir() and is_session(q))
            vids = sorted(q for q in p.iterdir() if q.suffix.lower() in VIDEO_SUFFIXES)
            if not subs and not vids:
                raise InputError(f"{p} holds no sessions (folders with meta.json) and no videos")
            out.extend(subs + vids)
        else:
            out.append(p)
    return tuple(out)


def command(args: argparse.Namespace) -> ReplayCommand:
    modes = tuple(Mode.parse(m.strip()) for m in args.modes.split(",") if m.strip())
    if not modes:
        raise ConfigError("--modes is empty")
    if args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    arb: ArbitrationConfig | None = None
    if args.config is not None or args.param:
        arb, _ = arbitration_config(args)
    rerun: Path | None = None
    if args.rerun is not None:
        rerun = Path(args.rerun)
        if rerun.suffix != ".rrd":
            raise ConfigError(f"--rerun must name a .rrd file, got {rerun}")
        if not rerun.parent.is_dir():
            raise ConfigError(f"--rerun: no such folder: {rerun.parent}")
    return ReplayCommand(
        inputs=_expand(list(args.inputs)),
        modes=modes,
        out=Path(args.out),
        robot=args.robot,
        as_recorded=bool(args.as_recorded),
        retrack=bool(args.retrack),
        workers=int(args.workers),
        plots=not args.no_plots,
        arbitration=arb,
        rerun=rerun,
    )


#: One work unit: an input (index, path), the modes it runs, the command, and where its
#: Rerun parts go (None: no recording).
Unit = tuple[int, str, tuple[str, ...], "ReplayCommand", "str | None"]


def _rerun_sinks(
    parts: Path, index: int, recording_id: str, modes: tuple[str, ...], plant_meta: Any, camera: Any
) -> Any:
    """`sink_for(mode)`: each run's part file; the first mode's also holds the shared
    entities (the true goals, the camera) and the recording's layout."""
    from dsteleop.app.rrd.replay import write_part

    def sink_for(mode: Mode) -> Any:
        shared = mode.value == modes[0]
        part = parts / f"{index:05d}-{mode.value}.rrd"

        def sink(records: Any, scene: Any) -> None:
            write_part(
                part,
                recording_id,
                mode.value,
                records,
                scene,
                plant_meta if shared else None,
                camera if shared else None,
                modes if shared else None,
            )

        return sink

    return sink_for


def _work(unit: Unit) -> list[tuple[str, float, Any]]:
    """One input in some modes (runs in a worker process): (name, recorded_s, trace)."""
    from dsteleop.app.replay import core
    from dsteleop.app.session.reader import read_session

    index, path_s, mode_names, cmd, parts_s = unit
    path = Path(path_s)
    parts = None if parts_s is None else Path(parts_s)
    modes = [Mode.parse(m) for m in mode_names]
    # What the modes of a session share (camera, true goals, layout) goes with the first mode.
    all_modes = tuple(m.value for m in cmd.modes)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        from dsteleop.app.replay.video import replay_video
        from dsteleop.app.rrd.replay import Camera

        sinks = None
        if parts is not None:
            sinks = _rerun_sinks(parts, index, path.name, all_modes, None, Camera(path))
        traces, recorded_s = replay_video(path, modes, cmd.arbitration, sinks)
        return [(path.name, recorded_s, tr) for tr in traces]
    session = read_session(path)
    if cmd.arbitration is not None:
        loop = {**session.meta.get("loop", {}), "arbitration": cmd.arbitration.to_dict()}
        session = dataclasses.replace(session, meta={**session.meta, "loop": loop})
    sink_for = None
    if parts is not None:
        sink_for = _rerun_sinks(
            parts, index, session.name, all_modes, session.meta.get("plant", {}), _camera(session)
        )
    if cmd.as_recorded:
        traces = [core.as_recorded(session)]
        if parts is not None:
            from dsteleop.app.rrd.replay import write_part

            write_part(
                parts / f"{index:05d}-{session.mode.value}.rrd",
                session.name,
                session.mode.value,
                session.records,
                None,
                session.meta.get("plant", {}),
                _camera(session),
                (session.mode.value,),
            )
    elif cmd.retrack:
        from dsteleop.app.replay.video import replay_retracked

        traces = replay_retracked(session, modes, sink_for)
    else:
        traces = [
            core.replay_session(
                session, m, robot=cmd.robot, sink=None if sink_for is None else sink_for(m)
            )
            for m in modes
        ]
    return [(session.name, tr.recorded_s, tr) for tr in traces]


def _camera(session: Any) -> Any:
    """The session's camera for a recording: its video and the frames' capture times."""
    from dsteleop.app.rrd.replay import Camera

    if session.video is None or session.frames is None:
        return None
    times = tuple(
        float(json.loads(line)["t_capture"])
        for line in session.frames.read_text().splitlines()
        if line.strip()
    )
    return Camera(session.video, times)


def run(args: argparse.Namespace) -> int:
    cmd = command(args)
    from dsteleop.app.replay import core
    from dsteleop.app.session.reader import read_session

    out = prepare_out_dir(cmd.out)
    # Validate every input before the long work starts.
    for p in cmd.inputs:
        if p.suffix.lower() not in VIDEO_SUFFIXES:
            read_session(p)
    t0 = time.perf_counter()
    # Work units: a recorded session replays once per mode, each mode its own unit (the
    # modes of one session run in parallel); a video or a re-tracked session is one unit
    # (tracked once, then run in every mode).
    names = tuple(m.value for m in cmd.modes)
    parts: Path | None = None
    if cmd.rerun is not None:
        parts = Path(tempfile.mkdtemp(prefix=".rerun-parts-", dir=cmd.rerun.parent))
    units: list[tuple[int, Unit]] = []
    for i, p in enumerate(cmd.inputs):
        whole = cmd.as_recorded or cmd.retrack or p.suffix.lower() in VIDEO_SUFFIXES
        for group in [names] if whole else [(m,) for m in names]:
            units.append((i, (i, str(p), group, cmd, None if parts is None else str(parts))))
    by_input: dict[int, list[tuple[str, float, Any]]] = {}
    try:
        with Progress(len(units), sys.stderr, sys.stderr.isatty(), "replay", "runs") as bar:
            if cmd.workers == 1 or len(units) == 1:
                for i, u in units:
                    by_input.setdefault(i, []).extend(_work(u))
                    bar.advance()
            else:
                import dsteleop.app.plants.kitchen  # noqa: F401  (loaded once; workers share it)

                with ProcessPoolExecutor(max_workers=cmd.workers) as pool:
                    for (i, _), res in zip(units, pool.map(_work, [u for _, u in units])):
                        by_input.setdefault(i, []).extend(res)
                        bar.advance()
        if parts is not None and cmd.rerun is not None:
            from dsteleop.app.rrd.files import merge

            merge(sorted(parts.glob("*.rrd")), cmd.rerun)
    finally:
        if parts is not None:
            shutil.rmtree(parts, ignore_errors=True)
    wall = time.perf_counter() - t0
    sessions = []
    all_traces = []
    for i in sorted(by_input):
        res = by_input[i]
        traces = [tr for _, _, tr in res]
        all_traces.extend(traces)
        sessions.append(core.session_summary(res[0][0], res[0][1], traces))
    used = sorted(
        {tr.mode.value for tr in all_traces}, key=lambda m: names.index(m) if m in names else 99
    )
    agg, tests = core.aggregate(sessions, used)
    recorded = sum(s["duration_s"] for s in sessions)
    runs = 1 if cmd.as_recorded else len(names)
    metrics_json = {
        "wall_s": round(wall, 3),
        "recorded_s": round(recorded, 3),
        "speed_x_realtime": round(recorded * runs / wall, 2) if wall > 0 else None,
        "as_recorded": cmd.as_recorded,
        "robot": cmd.robot,
        "sessions": sessions,
        "modes": agg,
        "tests": tests,
    }
    (out / "metrics.json").write_text(
        json.dumps(core.jsonable(metrics_json), indent=2, allow_nan=False) + "\n"
    )
    if cmd.plots:
        from dsteleop.app.replay.plots import plot_traces

        plot_traces(all_traces, out)
    json.dump(
        {
            "metrics": str(out / "metrics.json"),
            "wall_s": metrics_json["wall_s"],
            "sessions": len(sessions),
            "rerun": None if cmd.rerun is None else str(cmd.rerun),
        },
        sys.stdout,
    )
    sys.stdout.write("\n")
    return 0
