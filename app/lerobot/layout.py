"""The LeRobot v3.0 layout as dsteleop writes it: paths, features, frame columns, statistics.

A dataset is a folder (docs/datasets.md has the mapping column by column):

    meta/info.json                          codebase_version "v3.0", fps, features, totals,
                                            path templates (LeRobot's keys only)
    meta/stats.json                         per feature: min, max, mean, std, count, q01..q99
    dsteleop/dataset.json                   marks a dataset dsteleop wrote (`MARK`)
    dsteleop/ticks/chunk-000/file-000.parquet  dsteleop's own: each tick's full record, what
                                            a replay of the dataset reads (LeRobot ignores it)
    meta/tasks.parquet                      task_index, with the task string as the pandas
                                            index ("task")
    meta/episodes/chunk-000/file-000.parquet one row per episode: its frames
                                            (dataset_from_index, dataset_to_index), files,
                                            video span, stats/<feature>/<stat>, and dsteleop's
                                            own (dsteleop/outcome, dsteleop/mode, ...)
    data/chunk-000/file-000.parquet         one row per tick (frame), episodes back to back
    videos/observation.images.camera/chunk-000/file-000.mp4   the camera, one frame per tick

One frame is one control tick: `timestamp` is frame_index / fps (what LeRobot's reader
expects: evenly spaced frames, and the video frame at `from_timestamp + timestamp`), the
loop's own time of the tick rides along in `dsteleop.t_s`, and the camera frame's capture
time in `dsteleop.camera_t_s`, both since the episode's first tick (`dsteleop/t_start_s` in
the episode table, the loop's clock then): LeRobot's reader hands every float column to
PyTorch as float32, whose 24-bit mantissa keeps a time t to about t * 6e-8 s (1 us at 16 s,
2 us at a minute, 4 us at the trials' default limit of 120 s), where the loop's clock
itself (a monotonic clock, days of uptime: 1e5 s and more) would lose milliseconds
(`MARK_VERSION` 2; 1 held the loop's clock itself).
`observation.state` is the robot's achieved palm pose and finger openness when the tick
started (the previous tick's result, or the reset state at an episode's first tick), then,
for a session that recorded them, the robot's joint positions at the same moment; `action`
the state the tick commanded (X_next), the palm pose and openness only. The robot's goal:
`observation.goal_belief` its belief over the task's goal candidates after the tick (the
kitchen's utensils and the bin, `goal_candidates`; a robot told its goal is certain of it:
1 on the told utensil in the pick phase, on the bin after), `observation.goal_confidence` its
confidence per dimension and `observation.goal_confidence_joint` in the whole goal (1 when
told; docs/METHOD.md §10). Statistics are those
of LeRobot's `compute_stats` (quantiles exact here, where LeRobot estimates them from
histograms); strings have none.

Only pyarrow and numpy here (no pandas): `tasks.parquet` carries the pandas metadata that
makes the task string its index when pandas reads it.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pyarrow.parquet as pq  # type: ignore[import-untyped]
from numpy.typing import NDArray

from dsteleop.app.jsonable import jsonable
from dsteleop.app.session.schema import TickRecord, encode
from dsteleop.arbitration import HandState
from dsteleop.arbitration.se3 import quat_wxyz_from_matrix
from dsteleop.errors import InputError
from dsteleop.robot.task import Phase

Array = NDArray[np.float64]

CODEBASE_VERSION = "v3.0"
#: The file that marks a dataset dsteleop wrote: its layout's version, dsteleop's version and
#: the tick records' schema (beside LeRobot's files: LeRobot warns about keys it does not know
#: in info.json, and drops them when it rewrites the file).
MARK = "dsteleop/dataset.json"
#: 2: `dsteleop.t_s` and `dsteleop.camera_t_s` since the episode's start (`T_START`); 1: on
#: the loop's clock.
MARK_VERSION = 2
#: The episode table's column with the loop's time of each episode's first tick [s]: what
#: the time columns count from (float64 there: LeRobot leaves the episode table's values as
#: they are).
T_START = "dsteleop/t_start_s"
CAMERA = "observation.images.camera"
INFO = "meta/info.json"
STATS = "meta/stats.json"
TASKS = "meta/tasks.parquet"
CHUNKS_SIZE = 1000
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
#: The tick as `ticks.jsonl` holds it (schema.encode): what a replay of the dataset reads;
#: in a table of its own beside the frames (index, episode_index, tick), so that the frames
#: hold numbers only (LeRobot computes no statistics of strings, and checkers flag them).
TICK = "tick"
TICKS_PATH = "dsteleop/ticks/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
#: The palm pose's components in `observation.state` and `action`: position [m] in the
#: robot's base frame, orientation as a unit quaternion (x, y, z, w), then finger openness.
POSE_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw")
#: A joint's name in `observation.state`: this prefix and the URDF joint's name (its
#: position in rad, or m for a prismatic joint: the session's `joint_units`).
JOINT_PREFIX = "joint."
#: dsteleop's per-dimension columns: feature -> the ArbitrationStep array it holds.
PER_DIM = {
    "observation.alpha": "alpha",
    "observation.p_human": "P_human",
    "observation.p_robot": "P_robot",
    "observation.willingness": "B",
    "action.human": "U_human",
    "action.robot": "U_robot",
}
DEFAULT_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")
#: The robot's goal (module docstring): its belief over the candidates, its confidence.
GOAL_BELIEF = "observation.goal_belief"
GOAL_CONFIDENCE = "observation.goal_confidence"
GOAL_CONFIDENCE_JOINT = "observation.goal_confidence_joint"
#: The place phase's one candidate.
PLACE_CANDIDATE = "bin"


def goal_candidates(meta: Mapping[str, Any]) -> tuple[str, ...]:
    """The goal candidates of a session's task as `GOAL_BELIEF` names them: the kitchen's
    utensils, then the bin; () for a task without utensils (no `GOAL_BELIEF` column)."""
    utensils = (meta.get("plant") or {}).get("utensils") or ()
    return (*(str(u) for u in utensils), PLACE_CANDIDATE) if utensils else ()


def rel(template: str, index: int, video_key: str = "") -> str:
    """The relative path of file `index` (chunk = index // CHUNKS_SIZE) of a path template."""
    return template.format(
        chunk_index=index // CHUNKS_SIZE, file_index=index % CHUNKS_SIZE, video_key=video_key
    )


def action_names(dims: Sequence[str]) -> list[str]:
    """The components of `action`: the palm pose, then the fingers' openness."""
    return [*POSE_NAMES, *dims[6:]]


def state_names(dims: Sequence[str], joint_names: Sequence[str] = ()) -> list[str]:
    """The components of `observation.state`: those of `action`, then the joints (if any)."""
    return [*action_names(dims), *(JOINT_PREFIX + n for n in joint_names)]


def features(
    dims: Sequence[str],
    camera: Mapping[str, Any] | None,
    joint_names: Sequence[str] = (),
    candidates: Sequence[str] = (),
) -> dict[str, Any]:
    """info.json's `features` (`camera`: the video's info block, or None without video;
    `joint_names`: the robot's joints the sessions recorded, or none; `candidates`: the
    task's goal candidates, `goal_candidates`, or none)."""

    def vec(names: list[str]) -> dict[str, Any]:
        return {"dtype": "float32", "shape": [len(names)], "names": names}

    out: dict[str, Any] = {
        "observation.state": vec(state_names(dims, joint_names)),
        "action": vec(action_names(dims)),
    }
    for key in PER_DIM:
        out[key] = vec(list(dims))
    out["observation.arbitrated"] = {"dtype": "int64", "shape": [1], "names": None}
    if candidates:
        out[GOAL_BELIEF] = vec(list(candidates))
    out[GOAL_CONFIDENCE] = vec(list(dims))
    out[GOAL_CONFIDENCE_JOINT] = {"dtype": "float32", "shape": [1], "names": None}
    if camera is not None:
        out[CAMERA] = {
            "dtype": "video",
            "shape": [camera["video.height"], camera["video.width"], 3],
            "names": ["height", "width", "channels"],
            "info": dict(camera),
        }
    out["dsteleop.t_s"] = {"dtype": "float64", "shape": [1], "names": None}
    if camera is not None:
        out["dsteleop.camera_t_s"] = {"dtype": "float64", "shape": [1], "names": None}
    out["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
    for key in DEFAULT_FEATURES[1:]:
        out[key] = {"dtype": "int64", "shape": [1], "names": None}
    return out


def state_vectors(states: Sequence[HandState]) -> NDArray[np.float32]:
    """States as `observation.state` lists them: position, quaternion (x, y, z, w), openness."""
    p = np.array([X.position for X in states], dtype=np.float64).reshape(-1, 3)
    q = quat_wxyz_from_matrix(np.array([X.rotation for X in states]).reshape(-1, 3, 3))
    g = np.array([X.openness for X in states], dtype=np.float64).reshape(len(states), -1)
    return np.concatenate([p, q[:, 1:], q[:, :1], g], axis=1).astype(np.float32)


T = TypeVar("T")


def at_start(
    records: Sequence[TickRecord], after: Callable[[TickRecord], T], reset: T | None
) -> list[T]:
    """A value of the robot when each tick started: the previous tick's `after`; at the
    first tick `reset` (the value at the episode's reset), or its own `after` without one."""
    first = reset if reset is not None else after(records[0])
    return [first, *(after(r) for r in records[:-1])]


def joint_vectors(records: Sequence[TickRecord], n_joints: int) -> NDArray[np.float32]:
    """The robot's joint positions when each tick started (`at_start`), one row per tick.

    Raises:
        InputError: a tick holds no joint positions, or another number of them.
    """

    def joints(r: TickRecord) -> Array | None:
        return r.plant.joints

    rows: list[Array | None] = at_start(records, joints, records[0].joints_reset)
    for k, q in enumerate(rows):
        if q is None or q.shape != (n_joints,):
            got = "none" if q is None else str(q.size)
            raise InputError(
                f"tick {records[0].k + k}: {got} joint positions where the session names "
                f"{n_joints} joints"
            )
    return np.array(rows, dtype=np.float32).reshape(len(records), n_joints)


def goal_columns(
    records: Sequence[TickRecord], candidates: Sequence[str], told: str
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """`GOAL_BELIEF` (n, K), `GOAL_CONFIDENCE` (n, D), `GOAL_CONFIDENCE_JOINT` (n,) of the
    ticks (module docstring): a tick's belief where it has one; a told goal's certainty
    (`told` in the ticks that started in the pick phase, the bin after) where not.

    Raises:
        InputError: a belief names a candidate that is not among `candidates`.
    """
    n, D, K = len(records), len(records[0].dims), len(candidates)
    belief = np.zeros((n, K), dtype=np.float32)
    conf = np.ones((n, D), dtype=np.float32)
    joint = np.ones(n, dtype=np.float32)
    started_in = at_start(records, lambda r: r.phase, None)
    for k, r in enumerate(records):
        b = r.belief
        if b is not None:
            conf[k], joint[k] = b.confidence, b.confidence_joint
            for name, p in zip(b.names, b.probability, strict=True):
                if name not in candidates:
                    raise InputError(
                        f"tick {r.k}: a belief over {name!r}, not one of the dataset's goal "
                        f"candidates ({', '.join(candidates) or 'none'})"
                    )
                belief[k, candidates.index(name)] = p
        elif K:
            name = told if started_in[k] is Phase.PICK else PLACE_CANDIDATE
            if name in candidates:
                belief[k, candidates.index(name)] = 1.0
    return belief, conf, joint


def frame_columns(
    records: Sequence[TickRecord],
    fps: float,
    episode_index: int,
    index0: int,
    task_index: int,
    camera_t_s: Sequence[float] | None,
    n_joints: int = 0,
    candidates: Sequence[str] = (),
    told: str = "",
) -> dict[str, Any]:
    """The data columns of one episode's ticks (module docstring): numpy arrays, strings as
    a list; the times since the episode's first tick. `camera_t_s`: the capture time of the
    video frame of each tick (on the loop's clock), or None;
    `n_joints`: the joints the session names (their positions end `observation.state`);
    `candidates`, `told`: the task's goal candidates and the utensil a told robot was told
    (`goal_columns`).

    Raises:
        InputError: the ticks do not hold `n_joints` joint positions each, or believe in a
            goal that is not a candidate.
    """
    n = len(records)
    dims = records[0].dims
    D = len(dims)
    t0 = records[0].t_s  # the time columns count from the episode's first tick (T_START)
    state = state_vectors(at_start(records, lambda r: r.X_current, records[0].X_reset))
    if n_joints:
        state = np.concatenate([state, joint_vectors(records, n_joints)], axis=1)
    cols: dict[str, Any] = {
        "observation.state": state,
        "action": state_vectors([r.X_next for r in records]),
    }
    arbitrated = np.array([r.step is not None for r in records])
    for key, name in PER_DIM.items():
        a = np.zeros((n, D), dtype=np.float32)
        for k, r in enumerate(records):
            if r.step is not None:
                a[k] = getattr(r.step, name)
        cols[key] = a
    cols["observation.arbitrated"] = arbitrated.astype(np.int64)
    belief, conf, joint = goal_columns(records, candidates, told)
    if candidates:
        cols[GOAL_BELIEF] = belief
    cols[GOAL_CONFIDENCE] = conf
    cols[GOAL_CONFIDENCE_JOINT] = joint
    cols["dsteleop.t_s"] = np.array([r.t_s for r in records], dtype=np.float64) - t0
    if camera_t_s is not None:
        cols["dsteleop.camera_t_s"] = np.asarray(camera_t_s, dtype=np.float64) - t0
    # As the session writer writes a tick (NaN as null: JSON has none).
    cols[TICK] = [
        json.dumps(jsonable(encode(r)), separators=(",", ":"), allow_nan=False) for r in records
    ]
    frame = np.arange(n, dtype=np.int64)
    cols["timestamp"] = (frame / fps).astype(np.float32)
    cols["frame_index"] = frame
    cols["episode_index"] = np.full(n, episode_index, dtype=np.int64)
    cols["index"] = index0 + frame
    cols["task_index"] = np.full(n, task_index, dtype=np.int64)
    return cols


# --- statistics -----------------------------------------------------------------------------


def feature_stats(a: NDArray[Any]) -> dict[str, NDArray[Any]]:
    """LeRobot's statistics of a feature over frames (axis 0): min, max, mean, std, count and
    the quantiles q01, q10, q50, q90, q99, each of the feature's shape ((1,) for a scalar)."""
    x = np.asarray(a, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    out: dict[str, NDArray[Any]] = {
        "min": x.min(axis=0),
        "max": x.max(axis=0),
        "mean": x.mean(axis=0),
        "std": x.std(axis=0),
        "count": np.array([x.shape[0]], dtype=np.int64),
    }
    for q in QUANTILES:
        out[f"q{round(q * 100):02d}"] = np.quantile(x, q, axis=0)
    return out


def image_stats(samples_rgb: NDArray[np.uint8]) -> dict[str, NDArray[Any]]:
    """LeRobot's statistics of a camera: per channel over sampled frames (N, H, W, 3), in
    [0, 1], each of shape (3, 1, 1). Computed from each channel's histogram of its 256
    values (exact: the quantiles interpolate linearly between order statistics, as
    `numpy.quantile` does)."""
    x = samples_rgb.reshape(-1, 3)
    n = x.shape[0]
    values = np.arange(256, dtype=np.float64)
    out: dict[str, list[float]] = {k: [] for k in ("min", "max", "mean", "std")}
    quantiles: dict[str, list[float]] = {f"q{round(q * 100):02d}": [] for q in QUANTILES}
    for c in range(3):
        hist = np.bincount(x[:, c], minlength=256).astype(np.float64)
        mean = float(hist @ values) / n
        out["mean"].append(mean)
        out["std"].append(float(np.sqrt(max(float(hist @ (values - mean) ** 2) / n, 0.0))))
        present = np.flatnonzero(hist)
        out["min"].append(float(present[0]))
        out["max"].append(float(present[-1]))
        upto = np.cumsum(hist)  # order statistic i (from 0) is the first value with upto > i
        for q, name in zip(QUANTILES, quantiles, strict=True):
            pos = q * (n - 1)
            lo, frac = int(np.floor(pos)), pos - np.floor(pos)
            v_lo = float(np.searchsorted(upto, lo, side="right"))
            v_hi = float(np.searchsorted(upto, min(lo + 1, n - 1), side="right"))
            quantiles[name].append(v_lo + frac * (v_hi - v_lo))
    stats: dict[str, NDArray[Any]] = {
        k: np.asarray(v).reshape(3, 1, 1) / 255.0 for k, v in {**out, **quantiles}.items()
    }
    stats["count"] = np.array([samples_rgb.shape[0]], dtype=np.int64)
    return stats


def sample_indices(n: int) -> list[int]:
    """Frames LeRobot samples for a camera's statistics (`compute_stats.sample_indices`)."""
    k = n if n < 100 else max(100, min(int(n**0.75), 10_000))
    return sorted({int(i) for i in np.round(np.linspace(0, n - 1, k))})


def aggregate_stats(parts: Sequence[Mapping[str, Mapping[str, NDArray[Any]]]]) -> dict[str, Any]:
    """The dataset's statistics from its episodes' (LeRobot's `aggregate_stats`: weighted
    mean, pooled variance, min of min, max of max; lower quantiles their minimum, upper ones
    their maximum, a bound where exact quantiles cannot be recovered)."""
    out: dict[str, Any] = {}
    for key in parts[0]:
        ss = [p[key] for p in parts]
        counts = np.stack([s["count"] for s in ss]).astype(np.float64)
        means = np.stack([s["mean"] for s in ss])
        var = np.stack([s["std"] ** 2 for s in ss])
        total = counts.sum(axis=0)
        c = counts
        while c.ndim < means.ndim:
            c = c[..., None]
        mean = (means * c).sum(axis=0) / total.reshape((-1,) + (1,) * (means.ndim - 2))
        pooled = ((var + (means - mean) ** 2) * c).sum(axis=0) / total.reshape(
            (-1,) + (1,) * (means.ndim - 2)
        )
        agg: dict[str, NDArray[Any]] = {
            "min": np.min(np.stack([s["min"] for s in ss]), axis=0),
            "max": np.max(np.stack([s["max"] for s in ss]), axis=0),
            "mean": mean,
            "std": np.sqrt(pooled),
            "count": total.astype(np.int64),
        }
        for q in QUANTILES:
            name = f"q{round(q * 100):02d}"
            qs = np.stack([s[name] for s in ss])
            agg[name] = qs.min(axis=0) if q <= 0.5 else qs.max(axis=0)
        out[key] = agg
    return out


def stats_json(stats: Mapping[str, Mapping[str, NDArray[Any]]]) -> dict[str, Any]:
    """Statistics as stats.json holds them (nested lists)."""
    return {k: {s: np.asarray(v).tolist() for s, v in d.items()} for k, d in stats.items()}


def flat_stats(stats: Mapping[str, Mapping[str, NDArray[Any]]]) -> dict[str, Any]:
    """Statistics as the episode table's columns: `stats/<feature>/<stat>` -> nested list."""
    return {
        f"stats/{k}/{s}": np.asarray(v).tolist() for k, d in stats.items() for s, v in d.items()
    }


# --- parquet ---------------------------------------------------------------------------------


def arrow_column(values: Any, feature: Mapping[str, Any]) -> pa.Array:
    """One data column as LeRobot's reader types it: a scalar per frame for shape (1,), a
    fixed-size list for a vector, a string."""
    dtype = feature["dtype"]
    if dtype == "string":
        return pa.array(list(values), type=pa.string())
    a = np.asarray(values, dtype=np.dtype(dtype))
    if list(feature["shape"]) == [1]:
        return pa.array(a.reshape(-1))
    n = int(feature["shape"][0])
    return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), n)


def data_table(columns: Mapping[str, Any], feats: Mapping[str, Any]) -> pa.Table:
    """The frames of episodes as an arrow table, in the order of `feats` (videos excluded)."""
    keys = [k for k, f in feats.items() if f["dtype"] != "video"]
    return pa.table({k: arrow_column(columns[k], feats[k]) for k in keys})


def ticks_table(columns: Mapping[str, Any]) -> pa.Table:
    """The ticks of episodes as they are replayed (`TICKS_PATH`)."""
    return pa.table(
        {
            "index": pa.array(columns["index"]),
            "episode_index": pa.array(columns["episode_index"]),
            TICK: pa.array(list(columns[TICK]), type=pa.string()),
        }
    )


def write_parquet(table: pa.Table, path: Any, row_groups: Sequence[int] = ()) -> None:
    """Write `table` (one row group per slice length in `row_groups`, e.g. per episode)."""
    with pq.ParquetWriter(str(path), table.schema, compression="snappy") as w:
        start = 0
        for n in row_groups or [table.num_rows]:
            w.write_table(table.slice(start, n))
            start += n


def tasks_table(tasks: Sequence[str]) -> pa.Table:
    """meta/tasks.parquet: `task_index`, and the task string as the pandas index "task" (so
    `pandas.read_parquet` gives LeRobot the frame it expects)."""
    table = pa.table(
        {
            "task_index": pa.array(range(len(tasks)), type=pa.int64()),
            "task": pa.array(list(tasks), type=pa.string()),
        }
    )
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": "task",
                "field_name": "task",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def info_json(
    fps: int,
    feats: Mapping[str, Any],
    total_episodes: int,
    total_frames: int,
    total_tasks: int,
    robot_type: str,
) -> dict[str, Any]:
    """meta/info.json."""
    has_video = any(f["dtype"] == "video" for f in feats.values())
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        "total_episodes": total_episodes,
        "total_frames": total_frames,
        "total_tasks": total_tasks,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200,
        "fps": fps,
        "splits": {"train": f"0:{total_episodes}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if has_video else None,
        "features": dict(feats),
    }
