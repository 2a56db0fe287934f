"""Sessions to a LeRobot v3.0 dataset (`dsteleop export --to lerobot`; docs/datasets.md).

Every input is checked before anything is written: the sessions read (a corrupt line or a
folder without its metadata is one line; a last line cut short by a killed process is
skipped with a warning, as replay does), one control rate among them equal to `--fps`, one
set of dimensions and of joints (one robot's joint positions in every session, or none in
any: `observation.state` has one shape), a camera in all of them or in none. The dataset
is written into a hidden staging folder beside `out` and renamed into place when complete:
an export that fails or is interrupted leaves no folder that looks like a dataset.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from dsteleop.app.lerobot import check_out_dir
from dsteleop.app.lerobot.camera import DEFAULT_CODEC, SessionFrames
from dsteleop.app.lerobot.layout import goal_candidates
from dsteleop.app.lerobot.writer import DatasetWriter, default_task, misfit, session_fps
from dsteleop.app.session.reader import Session, read_session, sessions_in
from dsteleop.errors import ConfigError, InputError

log = logging.getLogger(__name__)

Which = Literal["counted", "all"]


@dataclass(frozen=True)
class Plan:
    """What an export will write: the sessions, their rate, and whether they have a camera."""

    sessions: tuple[Session, ...]
    fps: int
    camera: bool
    episodes: int
    ticks: int


def episodes_of(session: Session, which: Which) -> list[Any]:
    """The session's episodes to export: all of them, or the counted ones (with an outcome)."""
    return [e for e in session.episodes if which == "all" or e.counted]


def plan(inputs: Sequence[Path], fps: int | None, which: Which) -> Plan:
    """Read and check every input (module docstring).

    Raises:
        InputError: an input is missing, not a session, corrupt, or empty; the sessions do
            not fit one dataset (rates, dimensions, joints, camera); nothing to export.
        ConfigError: `fps` is not the sessions' control rate.
    """
    folders: list[Path] = []
    for p in inputs:
        if not Path(p).exists():
            raise InputError(f"not found: {p}")
        found = sessions_in(Path(p))
        if not found:
            raise InputError(f"{p} is not a session and holds no sessions")
        folders.extend(found)
    sessions = tuple(read_session(f) for f in folders)
    rates = {round(session_fps(s), 6) for s in sessions}
    if len(rates) > 1:
        raise InputError(
            f"the sessions ran at different rates ({', '.join(f'{r:g}' for r in sorted(rates))} "
            "Hz); a dataset has one frame rate: export them separately"
        )
    rate = rates.pop()
    if abs(rate - round(rate)) > 1e-6:
        raise InputError(f"the sessions ran at {rate:g} Hz; a dataset's fps is a whole number")
    if fps is not None and fps != round(rate):
        raise ConfigError(
            f"--fps {fps}: the sessions ran at {rate:g} Hz and each tick is one frame (its "
            f"action is the tick's command); leave --fps out or give {round(rate)}"
        )
    for s in sessions[1:]:
        first = sessions[0]
        why = misfit(
            s, first.dims, first.joint_names, first.robot_name, goal_candidates(first.meta)
        )
        if why is not None:
            raise InputError(why)
    cams = {s.video is not None and s.frames is not None for s in sessions}
    if len(cams) > 1:
        without = [s.folder.name for s in sessions if s.video is None or s.frames is None]
        raise InputError(
            f"{without[0]} has no camera video while other sessions do; a dataset has its "
            "camera in every episode or in none: export them separately"
        )
    eps = [e for s in sessions for e in episodes_of(s, which)]
    if not eps:
        raise InputError(
            "no episode to export"
            + (
                " (none ended with an outcome; --episodes all exports them)"
                if which == "counted"
                else ""
            )
        )
    return Plan(
        sessions=sessions,
        fps=round(rate),
        camera=cams.pop(),
        episodes=len(eps),
        ticks=sum(e.n_ticks for e in eps),
    )


def write(
    p: Plan,
    root: Path,
    task: str | None,
    which: Which,
    one_file: bool = True,
    advance: Callable[[int], None] | None = None,
    codec: str = DEFAULT_CODEC,
) -> DatasetWriter:
    """Write the planned episodes into `root` (no staging; `export` stages)."""
    from dsteleop.app.replay.video import frame_times

    first = p.sessions[0]
    writer = DatasetWriter(
        root,
        p.fps,
        first.dims,
        p.camera,
        one_file,
        robot_type=first.robot_name,
        codec=codec,
        joint_names=first.joint_names,
        candidates=goal_candidates(first.meta),
    )
    for s in p.sessions:
        frames = None
        if p.camera:
            assert s.video is not None and s.frames is not None
            frames = SessionFrames(s.video, frame_times(s.frames))
        try:
            for e in episodes_of(s, which):
                writer.add(s.of_episode(e), task or default_task(e.utensil), frames)
                if advance is not None:
                    advance(e.n_ticks)
        finally:
            if frames is not None:
                frames.close()
    writer.close()
    return writer


def export(
    inputs: Sequence[Path],
    out: Path,
    task: str | None = None,
    fps: int | None = None,
    which: Which = "all",
    advance: Callable[[int], None] | None = None,
    checked: Plan | None = None,
    codec: str = DEFAULT_CODEC,
) -> dict[str, Any]:
    """Export sessions into a new dataset at `out` (module docstring); a summary.

    Raises:
        InputError, ConfigError: as `plan` and `check_out_dir` say.
    """
    out = Path(out)
    p = checked or plan(inputs, fps, which)
    check_out_dir(out)
    t0 = time.perf_counter()
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        staging.chmod(0o755)  # the dataset's folder as any made plainly (mkdtemp: private)
        writer = write(p, staging, task, which, True, advance, codec)
        if out.exists():
            out.rmdir()
        os.rename(staging, out)
    except OSError as exc:
        raise InputError(f"cannot write the dataset at {out}: {exc.strerror or exc}") from None
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    wall = time.perf_counter() - t0
    recorded = p.ticks / p.fps
    return {
        "dataset": str(out),
        "episodes": len(writer.episodes),
        "frames": writer.frames,
        "tasks": writer.tasks,
        "camera": p.camera,
        "codec": codec if p.camera else None,
        "fps": p.fps,
        "recorded_s": round(recorded, 3),
        "wall_s": round(wall, 3),
        "speed_x_realtime": round(recorded / wall, 2) if wall > 0 else math.inf,
    }
