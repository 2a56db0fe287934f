"""Reading a dsteleop-written LeRobot dataset back as sessions, one per episode.

Each episode of the dataset becomes the view of one episode of a session (`Session` with
`episode` set), as `Session.of_episode` gives it: the session's metadata (kept whole in the
episode table, `dsteleop/session_meta`), its tick records (decoded from the dataset's tick
table, exactly as from `ticks.jsonl`) and the recorded episode. So `dsteleop replay` replays
a dataset's episodes in any mode like a session's, and gets the same numbers.

Only the episodes info.json counts are read: a live recording killed between writing an
episode's files and its metadata leaves that episode out, as LeRobot's own metadata does.

The frame table's time columns count from each episode's start (`layout.MARK_VERSION` 2);
`frame_times` gives them back on the loop's clock, adding the episode table's
`dsteleop/t_start_s` (a dataset of layout 1 held the loop's clock itself). A replay needs
neither: the tick records hold the loop's times at full precision.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pyarrow.parquet as pq  # type: ignore[import-untyped]
from numpy.typing import NDArray

from dsteleop.app.jsonable import read_json
from dsteleop.app.lerobot import layout as L  # noqa: N812  (the layout, named once)
from dsteleop.app.session.episodes import Episode
from dsteleop.app.session.reader import Session
from dsteleop.app.session.schema import decode
from dsteleop.errors import InputError


def is_dataset(path: Path) -> bool:
    """A folder with a LeRobot dataset's info.json."""
    return (Path(path) / L.INFO).is_file()


@dataclass(frozen=True)
class Dataset:
    """A dataset read back.

    Attributes:
        root: its folder.
        info: meta/info.json.
        episodes: the episode table's rows (without the statistics), by episode index.
        sessions: each episode as a session's view of it.
        layout: the version of dsteleop's layout it was written in (`layout.MARK_VERSION`).
    """

    root: Path
    info: dict[str, Any]
    episodes: tuple[dict[str, Any], ...]
    sessions: tuple[Session, ...]
    layout: int = L.MARK_VERSION

    def t_start_s(self, episode: int) -> float:
        """The loop's time of the episode's first tick [s], what its frames' time columns
        count from (0 in a dataset of layout 1, whose columns held the loop's clock)."""
        if self.layout < 2:
            return 0.0
        return float(self.episodes[episode][L.T_START])


@dataclass(frozen=True)
class FrameTimes:
    """An episode's frame times on the loop's clock [s], float64 (`frame_times`).

    Attributes:
        t_s: each tick's start.
        camera_t_s: the capture time of each tick's camera frame, or None without a camera.
    """

    t_s: NDArray[np.float64]
    camera_t_s: NDArray[np.float64] | None


def frame_times(dataset: Dataset, episode: int) -> FrameTimes:
    """The frame table's times of one episode back on the loop's clock: its columns (since
    the episode's start) plus `Dataset.t_start_s` (module docstring).

    Raises:
        InputError: the data files cannot be read, or hold no frame of that episode.
    """
    root = dataset.root
    try:
        data = _parquet_rows(root, "data/*/*.parquet")
        if data is None:
            raise InputError(f"{root}: the dataset has no data file")
        mask = data.column("episode_index").to_numpy() == episode
        order = np.argsort(data.column("frame_index").to_numpy()[mask], kind="stable")
        t0 = dataset.t_start_s(episode)

        def column(name: str) -> NDArray[np.float64]:
            values = data.column(name).to_numpy()[mask][order]
            return np.asarray(values, dtype=np.float64) + t0

        cam = column("dsteleop.camera_t_s") if "dsteleop.camera_t_s" in data.column_names else None
        t = column("dsteleop.t_s")
    except (OSError, pa.ArrowException, KeyError, IndexError) as exc:
        raise InputError(f"{root}: malformed dataset ({type(exc).__name__}: {exc})") from None
    if not t.size:
        raise InputError(f"{root}: no frame of episode {episode}")
    return FrameTimes(t, cam)


def _parquet_rows(root: Path, pattern: str) -> pa.Table | None:
    paths = sorted(root.glob(pattern))
    if not paths:
        return None
    return pa.concat_tables([pq.read_table(p) for p in paths])


def read_info(root: Path) -> dict[str, Any]:
    """meta/info.json of a dataset dsteleop wrote.

    Raises:
        InputError: it is missing, unreadable, not v3.0, or not dsteleop's.
    """
    path = Path(root) / L.INFO
    info = read_json(path, "dataset metadata")
    if not isinstance(info, dict) or info.get("codebase_version") != L.CODEBASE_VERSION:
        version = info.get("codebase_version") if isinstance(info, dict) else None
        raise InputError(f"{root}: a LeRobot dataset of version {version!r}; this reads v3.0")
    if not (Path(root) / L.MARK).is_file():
        raise InputError(
            f"{root}: a LeRobot dataset that dsteleop did not write: it holds no tick records "
            "to replay"
        )
    return info


def read_dataset(root: Path) -> Dataset:
    """Read a dataset dsteleop wrote (module docstring).

    Raises:
        InputError: not such a dataset, or a file of it missing or malformed (one line).
    """
    root = Path(root)
    info = read_info(root)
    total = int(info.get("total_episodes", 0))
    layout = _layout_version(root)
    try:
        eps = _parquet_rows(root, "meta/episodes/*/*.parquet")
        ticks = _parquet_rows(root, "dsteleop/ticks/*/*.parquet")
        if eps is None or ticks is None:
            raise InputError(f"{root}: the dataset's episode or tick table is missing")
        keep = [c for c in eps.column_names if not c.startswith("stats/")]
        rows = {int(r["episode_index"]): r for r in eps.select(keep).to_pylist()}
        by_episode: dict[int, list[str]] = {}
        for e, text in zip(
            ticks.column("episode_index").to_pylist(), ticks.column(L.TICK).to_pylist()
        ):
            by_episode.setdefault(int(e), []).append(str(text))
        sessions = []
        for e in range(total):
            row = rows.get(e)
            if row is None:
                raise InputError(f"{root}: episode {e} is missing from the episode table")
            sessions.append(_episode_session(root, row, by_episode.get(e, [])))
    except (OSError, pa.ArrowException, KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{root}: malformed dataset ({type(exc).__name__}: {exc})") from None
    return Dataset(root, info, tuple(rows[e] for e in range(total)), tuple(sessions), layout)


def _layout_version(root: Path) -> int:
    """The layout version its mark file says (`layout.MARK`).

    Raises:
        InputError: the mark is unreadable, or of a layout newer than this reads.
    """
    path = root / L.MARK
    try:
        version = int(json.loads(path.read_text(encoding="utf-8"))["layout"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from None
    if not 1 <= version <= L.MARK_VERSION:
        raise InputError(
            f"{root}: written in dsteleop's dataset layout {version}; this version reads "
            f"layouts 1 to {L.MARK_VERSION}"
        )
    return version


def _episode_session(root: Path, row: dict[str, Any], lines: list[str]) -> Session:
    e = int(row["episode_index"])
    if len(lines) != int(row["length"]):
        raise InputError(
            f"{root}: episode {e} has {len(lines)} tick records for {row['length']} frames"
        )
    meta = json.loads(row["dsteleop/session_meta"])
    dims = tuple(str(d) for d in meta.get("dims", ()))
    records = tuple(decode(json.loads(x), dims) for x in lines)
    recorded = json.loads(row["dsteleop/episode"])
    episode = Episode.from_dict(recorded) if recorded else None
    if episode is None:
        from dsteleop.app.session.episodes import split

        episode = split(records)[0]
    episode = dataclasses.replace(episode, first=0, last=len(records) - 1)
    folder = root / str(row["dsteleop/session"])
    return Session(folder, meta, records, truncated=False, episode=episode)
