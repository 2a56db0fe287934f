"""Our own check of a dataset against the LeRobot v3.0 layout (every file, every column).

`problems(root)` lists what is wrong (empty: valid). What it checks:

    info.json       codebase_version v3.0, a whole fps, totals, path templates, features
                    with dtype, shape and names (a vector's names: one per component, none
                    twice)
    data            every parquet file's columns are the features without the video, each of
                    the arrow type LeRobot's reader casts to (scalar for shape (1,), fixed-size
                    list of the dtype otherwise); `index` runs 0..total_frames-1 without a gap;
                    per episode `frame_index` runs 0..length-1 and `timestamp` is
                    frame_index / fps (to 1e-4 s, LeRobot's tolerance)
    episodes        episode_index 0..total_episodes-1; `dataset_from_index`/`dataset_to_index`
                    back to back from 0 to total_frames with `length` between them; the data
                    file each names holds exactly those rows
    videos          each episode's file exists; its span is length / fps; every frame of the
                    file is stamped k / fps (to 1e-4 s) and of the feature's size, as many
                    as the episodes in it have frames
    camera ticks    the frame of each tick was captured within one frame period of the tick
                    (`dsteleop.camera_t_s` against `dsteleop.t_s`) while the camera delivered
                    frames
    goals           each frame's `observation.goal_belief` a probability vector (in [0, 1],
                    summing to 1 to 1e-4), the confidences in [0, 1]
    tasks           task_index 0..total_tasks-1, the task string as the pandas index "task"
    stats.json      every numeric feature with min, max, mean, std, count, q01..q99 of its
                    shape ((3, 1, 1) for the camera), count = total_frames
    dsteleop ticks  one tick record per frame, in the frames' order
    times           `dsteleop.t_s` counts from the episode's start (0 at its first frame), and
                    with the episode's `dsteleop/t_start_s` it is each tick record's loop time
                    (to 1 us)
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pyarrow.parquet as pq  # type: ignore[import-untyped]

from dsteleop.app.lerobot import layout as L  # noqa: N812  (the layout, named once)

STAT_KEYS = ("min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99")
TS_TOLERANCE_S = 1e-4
#: The frames' loop times (start + since the start, float64) against the tick records' [s].
T_TOLERANCE_S = 1e-6


def _expected_type(ft: dict[str, Any]) -> pa.DataType:
    value = pa.from_numpy_dtype(np.dtype(ft["dtype"])) if ft["dtype"] != "string" else pa.string()
    if list(ft["shape"]) == [1]:
        return value
    return pa.list_(value, int(ft["shape"][0]))


def problems(root: Path) -> list[str]:  # noqa: PLR0911  (each early return: nothing more to read)
    """What is wrong with the dataset at `root` (module docstring); empty when valid."""
    root = Path(root)
    out: list[str] = []
    try:
        info = json.loads((root / L.INFO).read_text())
    except (OSError, ValueError) as exc:
        return [f"{L.INFO}: {exc}"]
    for key in ("codebase_version", "fps", "features", "total_episodes", "total_frames",
                "total_tasks", "data_path", "chunks_size"):  # fmt: skip
        if key not in info:
            out.append(f"{L.INFO}: no {key}")
    if out:
        return out
    if info["codebase_version"] != L.CODEBASE_VERSION:
        out.append(f"{L.INFO}: codebase_version {info['codebase_version']!r}")
    fps = info["fps"]
    if not isinstance(fps, int) or fps <= 0:
        return [*out, f"{L.INFO}: fps {fps!r} is not a positive whole number"]
    feats: dict[str, Any] = info["features"]
    for k, ft in feats.items():
        if not {"dtype", "shape", "names"} <= set(ft):
            out.append(f"{L.INFO}: feature {k} lacks dtype, shape or names")
        elif isinstance(names := ft["names"], list) and ft["dtype"] != "video":
            n = int(ft["shape"][0])
            if len(names) != n or len(set(names)) != n:
                out.append(f"{L.INFO}: feature {k}: names {names} do not name its {n} values")
    for k in L.DEFAULT_FEATURES:
        if k not in feats:
            out.append(f"{L.INFO}: no {k} feature")
    total_frames, total_eps = int(info["total_frames"]), int(info["total_episodes"])
    videos = [k for k, ft in feats.items() if ft["dtype"] == "video"]
    columns = [k for k, ft in feats.items() if ft["dtype"] != "video"]

    # data
    tables: dict[Path, pa.Table] = {}
    for path in sorted((root / "data").glob("*/*.parquet")):
        t = pq.read_table(path)
        tables[path] = t
        rel = path.relative_to(root)
        if sorted(t.column_names) != sorted(columns):
            out.append(f"{rel}: columns {sorted(t.column_names)} != features {sorted(columns)}")
            continue
        for k in columns:
            want = _expected_type(feats[k])
            if t.schema.field(k).type != want:
                out.append(f"{rel}: {k} is {t.schema.field(k).type}, LeRobot reads {want}")
    if not tables:
        return [*out, "data: no parquet file"]
    if out:
        return out
    data = pa.concat_tables(list(tables.values()))
    index = data.column("index").to_numpy()
    if not np.array_equal(np.sort(index), np.arange(total_frames)) or data.num_rows != total_frames:
        out.append(f"data: index is not 0..{total_frames - 1} without gaps or repeats")
    ep_col = data.column("episode_index").to_numpy()
    frame = data.column("frame_index").to_numpy()
    ts = data.column("timestamp").to_numpy().astype(np.float64)

    # episodes
    eps_paths = sorted((root / "meta/episodes").glob("*/*.parquet"))
    if not eps_paths:
        return [*out, "meta/episodes: no parquet file"]
    eps = pa.concat_tables([pq.read_table(p) for p in eps_paths]).to_pylist()
    eps.sort(key=lambda r: int(r["episode_index"]))
    if [int(r["episode_index"]) for r in eps] != list(range(total_eps)):
        out.append(f"meta/episodes: episode_index is not 0..{total_eps - 1}")
        return out
    position = 0
    for r in eps:
        e, n = int(r["episode_index"]), int(r["length"])
        lo, hi = int(r["dataset_from_index"]), int(r["dataset_to_index"])
        if lo != position or hi - lo != n:
            out.append(
                f"episode {e}: dataset_from/to_index {lo}..{hi} (length {n}) not at {position}"
            )
        position = hi
        data_file = root / L.DATA_PATH.format(
            chunk_index=r["data/chunk_index"], file_index=r["data/file_index"]
        )
        t = tables.get(data_file)
        if t is None:
            out.append(f"episode {e}: its data file {data_file.relative_to(root)} is missing")
            continue
        sel = t.column("episode_index").to_numpy() == e
        idx = t.column("index").to_numpy()[sel]
        if not np.array_equal(idx, np.arange(lo, hi)):
            out.append(f"episode {e}: its rows in {data_file.name} are not index {lo}..{hi - 1}")
        m = ep_col == e
        if not np.array_equal(frame[m], np.arange(n)):
            out.append(f"episode {e}: frame_index is not 0..{n - 1}")
        elif np.abs(ts[m] - np.arange(n) / fps).max(initial=0.0) > TS_TOLERANCE_S:
            out.append(f"episode {e}: timestamp is not frame_index / fps")
    if position != total_frames:
        out.append(f"meta/episodes: the episodes end at {position}, not at {total_frames}")
    out += _videos(root, info, eps, videos)
    out += _camera_ticks(data, fps)
    out += _goals(data)
    out += _tasks(root, int(info["total_tasks"]))
    out += _stats(root, feats, total_frames)
    ticks = _ticks(root, data)
    out += ticks
    if not ticks:
        out += _times(root, data, eps)
    return out


def _videos(
    root: Path, info: dict[str, Any], eps: list[dict[str, Any]], keys: list[str]
) -> list[str]:
    import av

    out: list[str] = []
    fps = int(info["fps"])
    for key in keys:
        files: dict[Path, list[dict[str, Any]]] = {}
        for r in eps:
            path = root / info["video_path"].format(
                video_key=key,
                chunk_index=r[f"videos/{key}/chunk_index"],
                file_index=r[f"videos/{key}/file_index"],
            )
            span = r[f"videos/{key}/to_timestamp"] - r[f"videos/{key}/from_timestamp"]
            if abs(span - r["length"] / fps) > TS_TOLERANCE_S:
                out.append(f"episode {r['episode_index']}: {key} spans {span} s, not length / fps")
            files.setdefault(path, []).append(r)
        h, w = info["features"][key]["shape"][:2]
        for path, rows in files.items():
            if not path.is_file():
                out.append(f"{key}: {path.relative_to(root)} is missing")
                continue
            with av.open(str(path)) as c:
                stream = c.streams.video[0]
                times = [math.nan if f.time is None else f.time for f in c.decode(stream)]
                size = (stream.height, stream.width)
            n = sum(int(r["length"]) for r in rows)
            if len(times) != n:
                out.append(f"{path.relative_to(root)}: {len(times)} frames for {n} frames of data")
            elif not np.abs(np.asarray(times) - np.arange(n) / fps).max(initial=0.0) <= (
                TS_TOLERANCE_S  # (a frame without a time stamp is NaN: reported too)
            ):
                out.append(f"{path.relative_to(root)}: frames are not stamped k / fps")
            if size != (h, w):
                out.append(f"{path.relative_to(root)}: frames {size}, the feature says {(h, w)}")
            start = min(r[f"videos/{key}/from_timestamp"] for r in rows)
            if abs(start) > TS_TOLERANCE_S:
                out.append(f"{path.relative_to(root)}: its first episode starts at {start} s")
    return out


def _camera_ticks(data: pa.Table, fps: int) -> list[str]:
    """Each tick's frame within one frame period of the tick, while the camera delivered
    frames (ticks before its first frame or after its last get the nearest one; a camera
    slower than the loop has a longer period)."""
    if "dsteleop.camera_t_s" not in data.column_names:
        return []
    t = data.column("dsteleop.t_s").to_numpy()
    cam = data.column("dsteleop.camera_t_s").to_numpy()
    ep = data.column("episode_index").to_numpy()
    out = []
    for e in np.unique(ep):
        m = ep == e
        frames = np.unique(cam[m])
        period = max(1.0 / fps, float(np.median(np.diff(frames))) if frames.size > 1 else 0.0)
        live = (t[m] >= frames[0] - period) & (t[m] <= frames[-1] + period)
        lag = np.abs(t[m] - cam[m])[live]
        if lag.size and lag.max() > period + 1e-6:
            out.append(
                f"episode {e}: a tick's camera frame was captured {lag.max() * 1e3:.1f} ms from "
                f"the tick (one frame is {period * 1e3:.1f} ms)"
            )
    return out


def _goals(data: pa.Table) -> list[str]:
    """The robot's belief a probability vector on every frame, its confidences in [0, 1]."""
    out = []
    if L.GOAL_BELIEF in data.column_names:
        b = np.stack(data.column(L.GOAL_BELIEF).to_numpy(zero_copy_only=False)).astype(float)
        bad = np.flatnonzero(
            (b < -1e-6).any(1) | (b > 1 + 1e-6).any(1) | (np.abs(b.sum(1) - 1) > 1e-4)
        )
        if bad.size:
            out.append(f"{L.GOAL_BELIEF}: frame {bad[0]} is not a probability vector: {b[bad[0]]}")
    for key in (L.GOAL_CONFIDENCE, L.GOAL_CONFIDENCE_JOINT):
        if key not in data.column_names:
            continue
        col = data.column(key).to_numpy(zero_copy_only=False)
        c = np.stack(col).astype(float) if col.dtype == object else col.astype(float)
        if c.size and not ((c >= -1e-6) & (c <= 1 + 1e-6)).all():
            out.append(f"{key}: a confidence outside [0, 1]")
    return out


def _tasks(root: Path, total: int) -> list[str]:
    path = root / L.TASKS
    if not path.is_file():
        return [f"{L.TASKS} is missing"]
    t = pq.read_table(path)
    out = []
    meta = json.loads((t.schema.metadata or {}).get(b"pandas", b"{}"))
    if meta.get("index_columns") != ["task"] or "task" not in t.column_names:
        out.append(f"{L.TASKS}: the task string is not the pandas index 'task'")
    if t.column("task_index").to_pylist() != list(range(total)):
        out.append(f"{L.TASKS}: task_index is not 0..{total - 1}")
    return out


def _stats(root: Path, feats: dict[str, Any], total_frames: int) -> list[str]:
    try:
        stats = json.loads((root / L.STATS).read_text())
    except (OSError, ValueError) as exc:
        return [f"{L.STATS}: {exc}"]
    out = []
    for k, ft in feats.items():
        if ft["dtype"] == "string":
            continue
        s = stats.get(k)
        if s is None or set(s) != set(STAT_KEYS):
            out.append(f"{L.STATS}: {k} lacks statistics ({STAT_KEYS})")
            continue
        shape = (3, 1, 1) if ft["dtype"] == "video" else tuple(ft["shape"])
        for name in STAT_KEYS:
            got = np.asarray(s[name]).shape
            if name == "count":
                if got != (1,):
                    out.append(f"{L.STATS}: {k}/count has shape {got}")
                elif ft["dtype"] != "video" and s[name][0] != total_frames:
                    out.append(f"{L.STATS}: {k}/count {s[name][0]} != {total_frames} frames")
            elif got != shape:
                out.append(f"{L.STATS}: {k}/{name} has shape {got}, not {shape}")
    return out


def _ticks(root: Path, data: pa.Table) -> list[str]:
    paths = sorted((root / "dsteleop/ticks").glob("*/*.parquet"))
    if not paths:
        return ["dsteleop/ticks: no tick table"]
    t = pa.concat_tables([pq.read_table(p) for p in paths])
    if not np.array_equal(
        np.sort(t.column("index").to_numpy()), np.sort(data.column("index").to_numpy())
    ):
        return ["dsteleop/ticks: not one tick record per frame"]
    return []


def _times(root: Path, data: pa.Table, eps: list[dict[str, Any]]) -> list[str]:
    """The frames' time columns since each episode's start, the start in the episode table:
    together the tick records' loop times (module docstring)."""
    if "dsteleop.t_s" not in data.column_names:
        return []
    if any(L.T_START not in r for r in eps):
        return [f"meta/episodes: no {L.T_START} (the start the time columns count from)"]
    t = pa.concat_tables([pq.read_table(p) for p in sorted((root / "dsteleop/ticks").glob("*/*"))])
    loop_t = dict(
        zip(
            t.column("index").to_pylist(),
            (float(json.loads(x)["t"]) for x in t.column(L.TICK).to_pylist()),
            strict=True,
        )
    )
    index = data.column("index").to_numpy()
    ep = data.column("episode_index").to_numpy()
    frame = data.column("frame_index").to_numpy()
    rel = data.column("dsteleop.t_s").to_numpy()
    out = []
    for r in eps:
        e = int(r["episode_index"])
        m = ep == e
        if not m.any():
            continue
        first = rel[m][frame[m] == 0]
        if first.size and first[0] != 0.0:
            out.append(f"episode {e}: dsteleop.t_s is {first[0]:g} s at its first frame, not 0")
        want = np.array([loop_t[int(i)] for i in index[m]])
        err = np.abs(float(r[L.T_START]) + rel[m] - want).max()
        if err > T_TOLERANCE_S:
            out.append(
                f"episode {e}: {L.T_START} + dsteleop.t_s is {err:.3g} s off the tick records' "
                "loop times"
            )
    return out
