"""Writing LeRobot v3.0 datasets from sessions (`dsteleop export`) and live (`--record-lerobot`).

`DatasetWriter` takes episodes one at a time (a session's view of one episode, its task and
its camera frames). Two ways of filing them:

    export (`one_file=True`)   every episode back to back in file-000 of data, video and
                               episode table, written at `close`; the command writes into a
                               hidden staging folder and renames it into place at the end, so
                               an interrupted export leaves nothing that looks like a dataset.
    live   (`one_file=False`)  each episode its own files (file index = episode index, 1000
                               to a chunk, as the format allows), written when it ends: video,
                               data and episode table under temporary names, renamed, then
                               tasks, stats and info.json atomically last. A crash loses the
                               episode in progress; the ones finished stay a valid dataset
                               (info.json names only episodes whose files are complete).
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]

from dsteleop import __version__
from dsteleop.app.jsonable import jsonable
from dsteleop.app.lerobot import layout as L  # noqa: N812  (the layout, named once)
from dsteleop.app.lerobot.camera import (
    DEFAULT_CODEC,
    CameraEncoder,
    SessionFrames,
    frames_for_ticks,
    rgb,
)
from dsteleop.app.session.reader import Session
from dsteleop.app.session.schema import SCHEMA
from dsteleop.app.session.writer import write_json_atomic
from dsteleop.errors import InputError


def default_task(utensil: str) -> str:
    """The task string of an episode when the user gives none."""
    return f"pick up the {utensil or 'utensil'} and put it in the bin"


def session_fps(session: Session) -> float:
    """The session's control rate [Hz] (one tick is one frame)."""
    return float(session.meta.get("loop", {}).get("rate_hz", 30.0))


def _joints_text(names: Sequence[str]) -> str:
    return f"{len(names)} joints, {names[0]}..{names[-1]}" if names else "no joints"


def misfit(
    view: Session,
    dims: Sequence[str],
    joint_names: Sequence[str],
    robot: str,
    candidates: Sequence[str] | None = None,
) -> str | None:
    """Why the session `view` does not fit a dataset of these dimensions, joints, robot and
    goal candidates (None: not checked) (one line), or None when it fits."""
    if tuple(view.dims) != tuple(dims):
        return (
            f"{view.name}: dimensions {','.join(view.dims)} differ from the dataset's "
            f"({','.join(dims)}); export such sessions into separate datasets"
        )
    if view.joint_names != tuple(joint_names):
        return (
            f"{view.name}: its robot's joint positions ({_joints_text(view.joint_names)}) "
            f"differ from the dataset's ({_joints_text(joint_names)}); export sessions of "
            "different robots, or with and without joint positions, into separate datasets"
        )
    if view.robot_name != robot:
        return (
            f"{view.name}: its robot ({view.robot_name}) differs from the dataset's ({robot}); "
            "export sessions of different robots into separate datasets"
        )
    if candidates is not None and L.goal_candidates(view.meta) != tuple(candidates):
        return (
            f"{view.name}: its task's goal candidates "
            f"({', '.join(L.goal_candidates(view.meta)) or 'none'}) differ from the dataset's "
            f"({', '.join(candidates) or 'none'}); export them into separate datasets"
        )
    return None


def _atomic_path(path: Path) -> Path:
    """A temporary name beside `path` that no reader of the layout matches."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o644)  # as any file written plainly (mkstemp makes it private)
    return Path(tmp)


class DatasetWriter:
    """Episodes into a LeRobot v3.0 dataset (module docstring).

    Args:
        root: the dataset folder (created).
        fps: frames per second, the sessions' control rate.
        dims: the dimension names of every session.
        joint_names: the robot's joints every session recorded (their positions end
            `observation.state`), or () for sessions without joint positions.
        camera: the episodes come with camera frames (all of them, or none).
        one_file: export (everything in file-000, written at `close`) or live (a file per
            episode, written as it comes).
        robot_type: info.json's `robot_type`: the robot's description name (`Session.robot_name`).
        candidates: the task's goal candidates (`layout.goal_candidates`), every session's.
        codec: the camera's codec, "h264" (the default) or "av1" (`camera.CameraEncoder`).
    """

    def __init__(
        self,
        root: Path,
        fps: int,
        dims: Sequence[str],
        camera: bool,
        one_file: bool,
        robot_type: str,
        codec: str = DEFAULT_CODEC,
        joint_names: Sequence[str] = (),
        candidates: Sequence[str] = (),
    ) -> None:
        self.codec = codec
        self.joint_names = tuple(joint_names)
        self.candidates = tuple(candidates)
        self.root = Path(root)
        self.fps = fps
        self.dims = tuple(dims)
        self.camera = camera
        self.one_file = one_file
        self.robot_type = robot_type
        self.tasks: list[str] = []
        self.episodes: list[dict[str, Any]] = []
        self.stats: list[dict[str, Any]] = []
        self.frames = 0
        self._tables: list[pa.Table] = []
        self._ticks: list[pa.Table] = []
        self._encoder: CameraEncoder | None = None
        self._camera_info: dict[str, Any] | None = None
        self._video_t = 0.0

    def _features(self) -> dict[str, Any]:
        return L.features(
            self.dims,
            self._camera_info if self.camera else None,
            self.joint_names,
            self.candidates,
        )

    def _open_encoder(self, file_index: int, width: int, height: int) -> CameraEncoder:
        final = self.root / L.rel(L.VIDEO_PATH, file_index, L.CAMERA)
        path = final if self.one_file else _atomic_path(final)
        final.parent.mkdir(parents=True, exist_ok=True)
        if self._camera_info is not None:  # every episode's video the size of the first
            width, height = self._camera_info["video.width"], self._camera_info["video.height"]
        enc = CameraEncoder(path, self.fps, width, height, self.codec)
        if self._camera_info is None:
            self._camera_info = enc.info()
        return enc

    def add(self, view: Session, task: str, frames: SessionFrames | None) -> int:
        """Write (live) or stage (export) one episode: `view` is a session's view of it.

        Returns:
            its episode index in the dataset.

        Raises:
            InputError: the episode does not fit the dataset (dimensions, joints, camera, rate),
                or a tick lacks its joint positions.
        """
        records = view.records
        if not records:
            raise InputError(f"{view.name}: an episode without ticks")
        why = misfit(view, self.dims, self.joint_names, self.robot_type, self.candidates)
        if why is not None:
            raise InputError(why)
        if self.camera and frames is None:
            raise InputError(
                f"{view.name}: no camera video, but the dataset has a camera; export sessions "
                "with and without --record-video into separate datasets"
            )
        e = len(self.episodes)
        f = 0 if self.one_file else e
        if task not in self.tasks:
            self.tasks.append(task)
        ticks = [r.t_s for r in records]
        camera_t: list[float] | None = None
        samples: list[Any] = []
        if self.camera and frames is not None:
            if self._encoder is None or not self.one_file:
                self._encoder = self._open_encoder(f, frames.width, frames.height)
            enc = self._encoder
            idx = frames_for_ticks(frames.times, ticks)
            camera_t = [frames.times[i] for i in idx]
            wanted = set(L.sample_indices(len(records)))
            for k, i in enumerate(idx):
                frame = frames.frame(i)
                enc.write(frame)
                if k in wanted:
                    samples.append(rgb(frame))
        try:
            cols = L.frame_columns(
                records,
                self.fps,
                e,
                self.frames,
                self.tasks.index(task),
                camera_t,
                len(self.joint_names),
                self.candidates,
                (view.episode.utensil if view.episode is not None else "")
                or str((view.meta.get("plant") or {}).get("utensil", "")),
            )
        except InputError as exc:
            raise InputError(f"{view.name}: {exc}") from None
        feats = self._features()
        stats = {
            k: L.feature_stats(cols[k])
            for k, ft in feats.items()
            if ft["dtype"] not in ("video", "string")
        }
        n = len(records)
        row: dict[str, Any] = {
            "episode_index": e,
            "tasks": [task],
            "length": n,
            "data/chunk_index": f // L.CHUNKS_SIZE,
            "data/file_index": f % L.CHUNKS_SIZE,
            "dataset_from_index": self.frames,
            "dataset_to_index": self.frames + n,
        }
        if self.camera:
            stats[L.CAMERA] = L.image_stats(np.stack(samples))
            t0 = self._video_t if self.one_file else 0.0
            row[f"videos/{L.CAMERA}/chunk_index"] = f // L.CHUNKS_SIZE
            row[f"videos/{L.CAMERA}/file_index"] = f % L.CHUNKS_SIZE
            row[f"videos/{L.CAMERA}/from_timestamp"] = t0
            row[f"videos/{L.CAMERA}/to_timestamp"] = t0 + n / self.fps
            self._video_t = t0 + n / self.fps
        row["meta/episodes/chunk_index"] = f // L.CHUNKS_SIZE
        row["meta/episodes/file_index"] = f % L.CHUNKS_SIZE
        row.update(L.flat_stats(stats))
        ep = view.episode
        outcome = None if ep is None else ep.outcome
        row.update(
            {
                "dsteleop/session": view.folder.name,
                "dsteleop/session_episode": -1 if ep is None else ep.index,
                "dsteleop/mode": view.records[0].mode.value if ep is None else ep.mode,
                "dsteleop/end": "" if ep is None else ep.end,
                "dsteleop/counted": bool(ep is not None and ep.counted),
                "dsteleop/outcome": "none"
                if outcome is None
                else ("success" if outcome.success else "failure"),
                "dsteleop/outcome_reason": "" if outcome is None else outcome.reason,
                "dsteleop/utensil": "" if ep is None else ep.utensil,
                "dsteleop/duration_s": float(ticks[-1] - ticks[0] if ep is None else ep.duration_s),
                L.T_START: float(ticks[0]),
                "dsteleop/episode": json.dumps(jsonable(None if ep is None else ep.to_dict())),
                "dsteleop/session_meta": json.dumps(jsonable(view.meta), allow_nan=False),
            }
        )
        table = L.data_table(cols, feats)
        ticks_table = L.ticks_table(cols)
        self.episodes.append(row)
        self.stats.append(stats)
        self.frames += n
        if self.one_file:
            self._tables.append(table)
            self._ticks.append(ticks_table)
        else:
            self._commit_episode(table, ticks_table, row, f)
        return e

    def _commit_episode(
        self, table: pa.Table, ticks: pa.Table, row: dict[str, Any], f: int
    ) -> None:
        """Live: the episode's files under temporary names, renamed, then the metadata."""
        if self._encoder is not None:
            self._encoder.close()
            os.replace(self._encoder.path, self.root / L.rel(L.VIDEO_PATH, f, L.CAMERA))
            self._encoder = None
        for template, t in (
            (L.TICKS_PATH, ticks),
            (L.DATA_PATH, table),
            (L.EPISODES_PATH, pa.Table.from_pylist([row])),
        ):
            path = self.root / L.rel(template, f)
            tmp = _atomic_path(path)
            L.write_parquet(t, tmp)
            os.replace(tmp, path)
        self._write_meta()

    def _write_meta(self) -> None:
        """tasks.parquet, stats.json, then info.json (each replaced atomically)."""
        tasks = self.root / L.TASKS
        tmp = _atomic_path(tasks)
        L.write_parquet(L.tasks_table(self.tasks), tmp)
        os.replace(tmp, tasks)
        write_json_atomic(self.root / L.STATS, L.stats_json(L.aggregate_stats(self.stats)))
        info = L.info_json(
            self.fps,
            self._features(),
            len(self.episodes),
            self.frames,
            len(self.tasks),
            self.robot_type,
        )
        mark = {"layout": L.MARK_VERSION, "version": __version__, "tick_schema": SCHEMA}
        write_json_atomic(self.root / L.MARK, mark)
        write_json_atomic(self.root / L.INFO, info)

    def close(self) -> None:
        """Export: write everything staged (data, video, episode table, then the metadata).

        Raises:
            InputError: there was no episode to write.
        """
        if not self.one_file:
            if self._encoder is not None:  # an episode that never finished
                self._encoder.close()
                self._encoder.path.unlink(missing_ok=True)
                self._encoder = None
            return
        if not self.episodes:
            raise InputError("no episode to export")
        if self._encoder is not None:
            self._encoder.close()
            self._encoder = None
        lengths = [int(r["length"]) for r in self.episodes]
        for template, tables in ((L.DATA_PATH, self._tables), (L.TICKS_PATH, self._ticks)):
            path = self.root / L.rel(template, 0)
            path.parent.mkdir(parents=True, exist_ok=True)
            L.write_parquet(pa.concat_tables(tables), path, lengths)
        eps = self.root / L.rel(L.EPISODES_PATH, 0)
        eps.parent.mkdir(parents=True, exist_ok=True)
        L.write_parquet(pa.Table.from_pylist(self.episodes), eps)
        self._write_meta()
