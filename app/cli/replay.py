"""`dsteleop replay SESSION... --modes S,DS --out DIR`: headless replay and metrics.

Each session (or folder of sessions, or video file) is replayed in every requested mode
(`app/replay/core.py` says how), and DIR gets `metrics.json` (per session and mode, then
aggregated over sessions with the paper's tests) and PNG plots; one JSON line on stdout.
A replay is open loop: the recorded hand never saw the robot it now drives, so it does not
correct what that robot does; `metrics.json`, the JSON line and the plots say so (`"loop":
"open"`). Only `--as-recorded` is closed loop (the sessions as the operator ran them).

    --robot simulated    a fresh PyBullet robot per mode (the default): where each mode
                         would have taken the robot
    --robot recorded     the robot the session recorded, open loop: the recorded mode gives
                         back the recorded arbitration exactly; another mode, what it would
                         have computed along the same robot path
    --robot NAME|FILE    simulated, on that robot description instead of the session's
                         (its fingers must match the recorded hand's; a video: any robot)
    --as-recorded        the sessions' own ticks, as they happened (each in its recorded
                         mode: not with --modes)
    --retrack            re-run tracking on each session's video first
    --rerun FILE.rrd     also write a Rerun recording: one per episode (or video), every
                         replayed mode on one timeline (docs/recordings.md)
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
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dsteleop.app.cli.options import add_config_options, add_video_options, arbitration_config
from dsteleop.app.jsonable import jsonable
from dsteleop.app.outpaths import created_dir, output_dir, output_file
from dsteleop.app.tasks.progress import Progress
from dsteleop.arbitration import ArbitrationConfig, Mode, registered
from dsteleop.errors import ConfigError, InputError
from dsteleop.tracking.sources import check_rotation

if TYPE_CHECKING:  # heavy: imported where a replay runs
    from dsteleop.app.replay.core import RunSink, SinkFor
    from dsteleop.app.rrd.replay import Camera
    from dsteleop.app.session.reader import Session
    from dsteleop.app.session.schema import TickRecord
    from dsteleop.robot.scene import SceneGeometry

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v"}


@dataclass(frozen=True)
class ReplayCommand:
    """The `replay` command's settings.

    Attributes:
        inputs: session folders, video files and dsteleop-written LeRobot datasets, in order.
        modes: the modes to replay in.
        out: the output folder.
        robot: replay against a "simulated" (the session's), the "recorded" robot, or a
            simulated robot of a description (name or file).
        as_recorded: metrics of the sessions as they happened instead.
        retrack: re-track each session's video.
        workers: processes.
        plots: write the PNG plots.
        arbitration: hyper-parameters for the replays (None: each session's own).
        rotate: turn the frames of video inputs [deg clockwise] (None: their own rotation).
        allow_partial: accept videos that end before the frames they declare.
        rerun: write a Rerun recording of every run to this .rrd file, or None.
    """

    inputs: tuple[Path, ...]
    modes: tuple[Mode, ...]
    out: Path
    robot: str
    as_recorded: bool
    retrack: bool
    workers: int
    plots: bool
    arbitration: ArbitrationConfig | None
    rotate: int | None = None
    allow_partial: bool = False
    rerun: Path | None = None


def _robot_choice(robot: str) -> str:
    """`--robot`: "simulated", "recorded", or a robot description (checked now)."""
    if robot not in ("simulated", "recorded"):
        from dsteleop.app.cli.options import check_robot

        check_robot(robot)
    return robot


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="SESSION",
        help="session folders, folders of sessions, video files, or LeRobot datasets that "
        "dsteleop exported (docs/datasets.md)",
    )
    parser.add_argument(
        "--modes",
        default=None,
        help="comma-separated modes to replay in (default S,DS; any of "
        f"{','.join(m.value for m in registered())}; not with --as-recorded, which reports "
        "each session in the mode it was recorded in)",
    )
    parser.add_argument(
        "--out", required=True, type=output_dir, help="output folder for metrics.json and plots"
    )
    parser.add_argument(
        "--robot",
        default="simulated",
        metavar="simulated|recorded|NAME|FILE",
        help="replay against a fresh simulated robot (default: the session's), the recorded "
        "one, or a simulated robot description (iiwa, panda, or a .toml file)",
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
        type=output_file,
        default=None,
        metavar="FILE.rrd",
        help="also write a Rerun recording of every episode and mode (open with: rerun FILE.rrd)",
    )
    add_video_options(parser)
    add_config_options(parser)


def _expand(inputs: list[str]) -> tuple[Path, ...]:
    """Session folders and videos; a folder of them is opened. A folder with what a session
    holds but no meta.json is a session without its metadata: kept, so that reading it
    refuses it, never replayed as a plain video."""
    from dsteleop.app.lerobot.reader import is_dataset
    from dsteleop.app.session.reader import sessions_in

    out: list[Path] = []
    for s in inputs:
        p = Path(s)
        if not p.exists():
            raise InputError(f"not found: {p}")
        if is_dataset(p):  # a LeRobot dataset dsteleop wrote: its episodes replay
            out.append(p)
            continue
        subs = sessions_in(p)
        if p.is_dir() and subs != [p]:
            vids = sorted(q for q in p.iterdir() if q.suffix.lower() in VIDEO_SUFFIXES)
            if not subs and not vids:
                raise InputError(f"{p} holds no sessions (folders with meta.json) and no videos")
            out.extend(subs + vids)
        else:
            out.append(p)
    return tuple(out)


def command(args: argparse.Namespace) -> ReplayCommand:
    if args.modes is not None and args.as_recorded:
        raise ConfigError(
            "--modes does not apply to --as-recorded, which reports each session in the mode "
            "it was recorded in; leave one of them out"
        )
    text = "S,DS" if args.modes is None else str(args.modes)
    modes = tuple(Mode.parse(m.strip()) for m in text.split(",") if m.strip())
    if not modes:
        raise ConfigError("--modes is empty")
    if args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers}")
    arb: ArbitrationConfig | None = None
    if args.config is not None or args.param:
        arb = arbitration_config(args)
    rerun: Path | None = None
    if args.rerun is not None:
        from dsteleop.app.rrd.target import check_rrd_path

        rerun = check_rrd_path(Path(args.rerun))
    return ReplayCommand(
        inputs=_expand(list(args.inputs)),
        modes=modes,
        out=Path(args.out),
        robot=_robot_choice(args.robot),
        as_recorded=bool(args.as_recorded),
        retrack=bool(args.retrack),
        workers=int(args.workers),
        plots=not args.no_plots,
        arbitration=arb,
        rotate=check_rotation(args.rotate),
        allow_partial=bool(args.allow_partial),
        rerun=rerun,
    )


Unit = tuple[str, "int | None", tuple[str, ...], "ReplayCommand", "str | None"]
"""(input path, episode index (None: a video, or every episode of a re-tracked session),
modes, the command, the folder of Rerun part files (None: no recording))."""


def _rerun_sinks(
    parts: Path,
    modes: tuple[str, ...],
    plant_meta: dict[str, Any] | None,
    camera: Camera | None,
) -> SinkFor:
    """`sink_for(name, mode)`: each run's part file (recording id = the run's name: an
    episode, or a video); the first mode's also holds what the modes share (the true goals,
    the camera over the run's time, the recording's layout)."""
    from dsteleop.app.rrd.replay import write_part

    def sink_for(name: str, mode: Mode) -> RunSink:
        shared = mode.value == modes[0]
        part = parts / f"{name.replace('/', '~')}-{mode.value}.rrd"

        def sink(records: Sequence[TickRecord], scene: SceneGeometry | None) -> None:
            write_part(
                part,
                name,
                mode.value,
                records,
                scene,
                plant_meta if shared else None,
                camera if shared else None,
                modes if shared else None,
            )

        return sink

    return sink_for


def _camera(session: Session) -> Camera | None:
    """The session's camera for a recording: its video and the frames' capture times."""
    from dsteleop.app.replay.video import frame_times
    from dsteleop.app.rrd.replay import Camera

    if session.video is None or session.frames is None:
        return None
    return Camera(session.video, tuple(frame_times(session.frames)))


def _work(unit: Unit) -> list[Any]:
    """One input (or one episode of one) in some modes, in a worker process: its runs
    (`replay.core.Run`)."""
    from dsteleop.app.replay import core
    from dsteleop.app.session.reader import read_session

    path_s, index, mode_names, cmd, parts_s = unit
    path = Path(path_s)
    from dsteleop.app.lerobot.reader import is_dataset, read_dataset

    parts = None if parts_s is None else Path(parts_s)
    modes = [Mode.parse(m) for m in mode_names]
    # What the modes of a run share (camera, true goals, layout) goes with the first mode.
    all_modes = tuple(m.value for m in cmd.modes)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        from dsteleop.app.replay.video import replay_video
        from dsteleop.app.rrd.replay import Camera

        sinks = None
        if parts is not None:
            sinks = _rerun_sinks(parts, all_modes, None, Camera(path, rotate=cmd.rotate))
        traces, recorded_s = replay_video(
            path,
            modes,
            cmd.arbitration,
            rotate=cmd.rotate,
            allow_partial=cmd.allow_partial,
            sink_for=sinks,
            robot="iiwa" if cmd.robot in ("simulated", "recorded") else cmd.robot,
        )
        return [core.Run(path.name, path.name, None, recorded_s, tr) for tr in traces]
    if is_dataset(path):  # one episode of a dataset: a session's view of it
        assert index is not None
        session = read_dataset(path).sessions[index]
        index = 0
    else:
        session = read_session(path, warn_truncated=False)  # `run` read it first, said so
    if cmd.arbitration is not None:
        loop = {**session.meta.get("loop", {}), "arbitration": cmd.arbitration.to_dict()}
        session = dataclasses.replace(session, meta={**session.meta, "loop": loop})
    sink_for = None
    if parts is not None:
        sink_for = _rerun_sinks(parts, all_modes, session.meta.get("plant", {}), _camera(session))
    if cmd.retrack:
        from dsteleop.app.replay.video import replay_retracked

        return [
            core.Run(session.of_episode(ep).name, session.folder.name, ep, tr.recorded_s, tr)
            for ep, tr in replay_retracked(session, modes, cmd.allow_partial, sink_for)
        ]
    assert index is not None
    episode = session.episodes[index]
    view = session.of_episode(episode)
    if cmd.as_recorded:
        traces = [core.as_recorded(view)]
        if parts is not None:
            from dsteleop.app.rrd.replay import write_part

            own = view.mode.value
            write_part(
                parts / f"{view.name.replace('/', '~')}-{own}.rrd",
                view.name,
                own,
                view.records,
                None,
                view.meta.get("plant", {}),
                _camera(session),
                (own,),
            )
    else:
        traces = [
            core.replay_session(
                view,
                m,
                robot=cmd.robot,
                sink=None if sink_for is None else sink_for(view.name, m),
            )
            for m in modes
        ]
    return [core.Run(view.name, session.folder.name, episode, tr.recorded_s, tr) for tr in traces]


def run(args: argparse.Namespace) -> int:
    cmd = command(args)
    # A replay that fails leaves no empty --out behind (outpaths.created_dir).
    with created_dir(cmd.out) as out:
        return _run(cmd, out)


def _run(cmd: ReplayCommand, out: Path) -> int:
    from dsteleop.app.lerobot.reader import is_dataset, read_dataset
    from dsteleop.app.replay import core
    from dsteleop.app.session.reader import read_session

    # Validate every input before the long work starts; a session's episodes are the units.

    episodes: dict[Path, int] = {}
    for p in cmd.inputs:
        if is_dataset(p):
            if cmd.retrack:
                raise ConfigError(
                    f"--retrack: {p} is a dataset; its camera video is re-encoded per tick, "
                    "re-track the sessions it was exported from"
                )
            episodes[p] = len(read_dataset(p).sessions)
        elif p.suffix.lower() not in VIDEO_SUFFIXES:
            episodes[p] = len(read_session(p).episodes)
    t0 = time.perf_counter()
    # Work units: an episode of a recorded session replays once per mode, each mode its own
    # unit (the modes run in parallel); a video or a re-tracked session is one unit (tracked
    # once, then every episode run in every mode).
    names = tuple(m.value for m in cmd.modes)
    parts: Path | None = None
    if cmd.rerun is not None:
        parts = Path(tempfile.mkdtemp(prefix=".rerun-parts-", dir=cmd.rerun.parent))
    parts_s = None if parts is None else str(parts)
    units: list[Unit] = []
    for p in cmd.inputs:
        if p.suffix.lower() in VIDEO_SUFFIXES or cmd.retrack:
            units.append((str(p), None, names, cmd, parts_s))
            continue
        for e in range(episodes[p]):
            for group in [names] if cmd.as_recorded else [(m,) for m in names]:
                units.append((str(p), e, group, cmd, parts_s))
    runs: list[Any] = []
    try:
        with Progress(len(units), sys.stderr, sys.stderr.isatty(), "replay", "runs") as bar:
            if cmd.workers == 1 or len(units) == 1:
                for u in units:
                    runs.extend(_work(u))
                    bar.advance()
            else:
                import dsteleop.app.plants.kitchen  # noqa: F401  (loaded once; workers share it)

                with ProcessPoolExecutor(max_workers=cmd.workers) as pool:
                    for res in pool.map(_work, units):
                        runs.extend(res)
                        bar.advance()
        if parts is not None and cmd.rerun is not None:
            from dsteleop.app.rrd.files import merge

            merge(sorted(parts.glob("*.rrd")), cmd.rerun)
    finally:
        if parts is not None:
            shutil.rmtree(parts, ignore_errors=True)
    wall = time.perf_counter() - t0
    entries = core.episode_summaries(runs)
    all_traces = [r.trace for r in runs]
    used = sorted(
        {tr.mode.value for tr in all_traces}, key=lambda m: names.index(m) if m in names else 99
    )
    agg, tests = core.aggregate(entries, used)
    for note in core.test_notes(tests):
        log.warning("%s", note)
    recorded = sum(e["duration_s"] for e in entries)
    n_runs = 1 if cmd.as_recorded else len(names)
    loop_kind = core.loop_kind(cmd.as_recorded)
    log.info("replay: %s", core.LOOP_NOTES[loop_kind])
    metrics_json = {
        "loop": loop_kind,
        "loop_note": core.LOOP_NOTES[loop_kind],
        "wall_s": round(wall, 3),
        "recorded_s": round(recorded, 3),
        "speed_x_realtime": round(recorded * n_runs / wall, 2) if wall > 0 else None,
        "as_recorded": cmd.as_recorded,
        "robot": cmd.robot,
        "episodes": entries,
        "modes": agg,
        "tests": tests,
        "divergence": core.divergences(all_traces),
    }
    (out / "metrics.json").write_text(
        json.dumps(jsonable(metrics_json), indent=2, allow_nan=False) + "\n"
    )
    if cmd.plots:
        from dsteleop.app.replay.plots import plot_traces

        plot_traces(all_traces, out, open_loop=loop_kind == "open")
    json.dump(
        {
            "metrics": str(out / "metrics.json"),
            "loop": loop_kind,
            "wall_s": metrics_json["wall_s"],
            "inputs": len(cmd.inputs),
            "episodes": len(entries),
            "counted": sum(bool(e["counted"]) for e in entries),
            "rerun": None if cmd.rerun is None else str(cmd.rerun),
        },
        sys.stdout,
    )
    sys.stdout.write("\n")
    return 0
