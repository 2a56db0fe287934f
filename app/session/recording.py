"""A loop's recordings: the session's lifecycle, apart from the loop that feeds it.

    start(folder, meta)   a new session folder (meta.json), the outputs told
    put(record, utensil)  each tick: written (on the recorder's thread), split into
                          episodes (`episodes.EpisodeSplitter`); the record comes back with
                          the recording's state (`schema.RecordingStatus`), for the page
    stop(extra_meta)      the open episode ends "stopped", meta.json is completed

At most one session is open at a time; `folders` lists every one, in order. What is written
beside a session (the camera's video, a live LeRobot dataset: `ports.Output`) is told when
it starts (`start_session`) and closes (`stop_session`, before its last episode), and gets
each episode once its ticks are written (`episode`, on the recorder's thread).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.ports import Output
from dsteleop.app.session.episodes import Episode, EpisodeSplitter
from dsteleop.app.session.schema import RecordingStatus, TickRecord
from dsteleop.app.session.writer import Recorder, SessionWriter

log = logging.getLogger(__name__)


class Recording:
    """The sessions of one loop (module docstring). Called from the loop's thread.

    Args:
        outputs: what is written beside each session.
    """

    def __init__(self, outputs: Sequence[Output] = ()) -> None:
        self._outputs = tuple(outputs)
        self._recorder: Recorder | None = None
        self._episodes = EpisodeSplitter()
        self._t0_s: float | None = None
        #: Every session folder recorded into, in order.
        self.folders: list[Path] = []

    @property
    def folder(self) -> Path | None:
        """The open session's folder, or None."""
        return None if self._recorder is None else self._recorder.folder

    def start(self, folder: Path, meta: dict[str, Any]) -> Path:
        """Open a new session in `folder` with `meta` (any open one is stopped first by the
        caller: `stop`)."""
        if self._recorder is not None:
            raise RuntimeError(f"a session is open: {self._recorder.folder}")
        sink = self._episode if self._outputs else None
        self._recorder = Recorder(SessionWriter(folder, meta), sink)
        self.folders.append(Path(folder))
        self._episodes = EpisodeSplitter()
        self._t0_s = None
        for out in self._outputs:
            out.start_session(Path(folder))
        log.info("recording to %s", folder)
        return Path(folder)

    def put(self, record: TickRecord, utensil: str) -> TickRecord:
        """Write the record; end an episode it ends; the record with the recording's state
        (as it is, when no session is open)."""
        recorder = self._recorder
        if recorder is None:
            return record
        line = recorder.lines
        recorder.put(record)
        ended = self._episodes.push(line, record, utensil)
        if ended is not None:
            recorder.end_episode(ended)
        if self._t0_s is None:
            self._t0_s = record.t_s
        status = RecordingStatus(
            folder=str(recorder.folder),
            elapsed_s=record.t_s - self._t0_s,
            episodes=recorder.episodes,
            episode=self._episodes.current,
        )
        return dataclasses.replace(record, recording=status)

    def stop(self, extra_meta: dict[str, Any]) -> None:
        """Close the open session (if any): the outputs finish what they write beside it,
        the open episode ends "stopped", meta.json is completed with `extra_meta` and the
        session's counts."""
        recorder = self._recorder
        if recorder is None:
            return
        for out in self._outputs:
            out.stop_session()
        last = self._episodes.finish("stopped")
        if last is not None:
            recorder.end_episode(last)
        recorder.close({"n_episodes": recorder.episodes, **extra_meta})
        log.info(
            "recording closed: %s (%d ticks, %d episodes)",
            recorder.folder,
            recorder.writer.n_ticks,
            recorder.episodes,
        )
        self._recorder = None

    def _episode(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        for out in self._outputs:
            out.episode(folder, meta, episode, ticks)
