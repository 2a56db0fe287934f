"""A LeRobot dataset written while recording (`dsteleop run|serve --record-lerobot DIR`).

The loop records its session as always (ticks.jsonl, and the camera's video.mp4 with
--record-video); each episode, once its ticks are in the session, is handed to
`LiveDataset.put` and written into the dataset on this module's own thread, at a lower CPU
priority than the loop: its own files under temporary names, renamed, then the metadata
(`writer.DatasetWriter`, live filing). A crash loses at most the episode in progress; the
dataset's finished episodes stay valid, and the session keeps every tick.

With a camera, an episode's frames are read from the session's video (fragmented MP4,
readable while it is written) once the frame recorder has written the frames up to the
episode's last tick (waiting at most `FRAME_WAIT_S`; later ticks take the last frame there).
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
from pathlib import Path
from typing import Any

from dsteleop.app.jsonable import jsonable
from dsteleop.app.lerobot import check_out_dir
from dsteleop.app.lerobot.camera import DEFAULT_CODEC, SessionFrames
from dsteleop.app.lerobot.layout import goal_candidates
from dsteleop.app.lerobot.writer import DatasetWriter, default_task
from dsteleop.app.session.episodes import Episode
from dsteleop.app.session.reader import Session
from dsteleop.app.session.schema import TickRecord, decode, encode
from dsteleop.app.session.video import FRAMES, VIDEO, lower_thread_priority

log = logging.getLogger(__name__)

#: How long an episode waits for the camera's frames to reach its last tick [s].
FRAME_WAIT_S = 2.0

Item = tuple[Path, dict[str, Any], Episode, tuple[TickRecord, ...]]


class LiveDataset:
    """Writes each recorded episode into the dataset at `root` (module docstring).

    Args:
        root: the dataset folder (new or empty).
        fps: the loop's rate [Hz] (a whole number).
        camera: the sessions record the camera (--record-video).
        task: every episode's task string (None: from its utensil).
        codec: the camera's codec, "h264" (the default) or "av1".

    Raises:
        InputError: `root` holds something or cannot be written.
    """

    def __init__(
        self,
        root: Path,
        fps: int,
        camera: bool,
        task: str | None = None,
        codec: str = DEFAULT_CODEC,
    ) -> None:
        check_out_dir(Path(root))
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.fps = fps
        self.camera = camera
        self.task = task
        self.codec = codec
        self.written = 0
        self.failed = 0
        self._writer: DatasetWriter | None = None
        self._q: queue.SimpleQueue[Item | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="dsteleop-lerobot", daemon=True)
        self._thread.start()

    def put(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        """An episode ended (the session's folder and metadata, the episode, its ticks):
        queue it (`session.writer.EpisodeSink`)."""
        if ticks:
            self._q.put((Path(folder), dict(meta), episode, ticks))

    def close(self) -> None:
        """Write what is queued, then stop the thread."""
        self._q.put(None)
        self._thread.join()
        if self._writer is not None:
            self._writer.close()

    def summary(self) -> dict[str, Any]:
        return {"dataset": str(self.root), "episodes": self.written, "failed": self.failed}

    def _run(self) -> None:
        lower_thread_priority()
        while (item := self._q.get()) is not None:
            folder, meta, episode, ticks = item
            try:
                self._write(folder, meta, episode, ticks)
                self.written += 1
            except Exception as exc:  # the loop and its session go on; this episode is lost
                self.failed += 1
                log.error("writing episode %d into %s failed: %s", episode.index, self.root, exc)

    def _write(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        # As the session's file holds them (outputs to 10 significant digits): the dataset
        # then equals an export of the session, and a replay of either gives the same.
        ticks = tuple(decode(jsonable(encode(r)), r.dims) for r in ticks)
        view = Session(
            folder,
            meta,
            ticks,
            truncated=False,
            episode=dataclasses.replace(episode, first=0, last=len(ticks) - 1),
        )
        view = view.of_episode(view.episode)  # type: ignore[arg-type]
        if self._writer is None:
            self._writer = DatasetWriter(
                self.root,
                self.fps,
                view.dims,
                self.camera,
                one_file=False,
                robot_type=view.robot_name,
                codec=self.codec,
                joint_names=view.joint_names,
                candidates=goal_candidates(view.meta),
            )
        frames = self._frames(folder, ticks[-1].t_s) if self.camera else None
        try:
            self._writer.add(view, self.task or default_task(view.episode.utensil), frames)  # type: ignore[union-attr]
        finally:
            if frames is not None:
                frames.close()

    def _frames(self, folder: Path, t_last_s: float) -> SessionFrames | None:
        """The session's frames once they reach `t_last_s` (or after `FRAME_WAIT_S`)."""
        from dsteleop.app.replay.video import frame_times

        index = folder / FRAMES
        deadline = time.monotonic() + FRAME_WAIT_S
        times: list[float] = []
        while True:
            times = frame_times(index) if index.is_file() else []
            if (times and times[-1] >= t_last_s) or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        if not times:
            raise RuntimeError(f"{folder}: no camera frame recorded")
        return SessionFrames(folder / VIDEO, times)
