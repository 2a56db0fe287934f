"""Tick records -> Rerun columns (entity paths: `layout`).

Everything is sent as columns (`RecordingStream.send_columns`): one call per entity for a
whole run or a batch of ticks, not one call per tick and entity, so a replay writes in a
fraction of its own time and a live logger keeps up from its own thread. Rotations are sent
as quaternions (x, y, z, w, Rerun's order), converted once here from the rotation matrices
every state holds.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import NDArray

from dsteleop.app.rrd import layout
from dsteleop.app.session.schema import Status, TickRecord
from dsteleop.arbitration import STEP_ARRAYS, HandState
from dsteleop.arbitration.se3 import quat_wxyz_from_matrix
from dsteleop.robot.scene import SceneGeometry, VisualGeometry

Array = NDArray[np.float64]
JPEG = "image/jpeg"
AXIS_LENGTH_M = 0.05  # the drawn axes of a pose


def _time(t_s: Array | Sequence[float]) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(layout.TIMELINE, duration=np.asarray(t_s, dtype=np.float64))]


def xyzw(R: Array) -> Array:
    """Quaternions (..., 4) in Rerun's (x, y, z, w) order of rotation matrices (..., 3, 3)."""
    q = quat_wxyz_from_matrix(R)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _quat(q_xyzw: Any) -> rr.Quaternion:
    """A quaternion (x, y, z, w) for `rr.Transform3D`."""
    return rr.Quaternion(xyzw=np.asarray(q_xyzw, dtype=np.float32))


def _send_poses(rec: rr.RecordingStream, path: str, t_s: Array, p: Array, R: Array) -> None:
    if len(t_s) == 0:
        return
    rec.send_columns(
        path,
        indexes=_time(t_s),
        columns=rr.Transform3D.columns(translation=p, quaternion=xyzw(R)),
    )


def _send_texts(rec: rr.RecordingStream, path: str, t_s: Sequence[float], texts: list[str]) -> None:
    if texts:
        rec.send_columns(path, indexes=_time(t_s), columns=rr.TextLog.columns(text=texts))


def log_run(
    rec: rr.RecordingStream,
    root: str,
    records: Sequence[TickRecord],
    t0_s: float,
    scene: SceneGeometry | None = None,
) -> None:
    """A run's ticks under `root`, on the timeline `layout.TIMELINE` (t - t0_s [s]).

    Every per-dimension quantity gets one row per tick (NaN where the arbitration did not
    run); poses, events and lost-hand intervals where they exist, and the scene's frame
    poses where the plant exported them (`scene` names the frames; its shapes are logged
    once by `log_scene_geometry`).
    """
    if not records:
        return
    T = len(records)
    dims = records[0].dims
    t = np.array([r.t_s for r in records], dtype=np.float64) - t0_s
    arrays = {q: np.full((T, len(dims)), np.nan) for q in STEP_ARRAYS}
    for k, r in enumerate(records):
        if r.step is not None:
            for q in STEP_ARRAYS:
                arrays[q][k] = getattr(r.step, q)
    for q, values in arrays.items():
        for i, dim in enumerate(dims):
            rec.send_columns(
                layout.series(root, q, dim),
                indexes=_time(t),
                columns=rr.Scalars.columns(scalars=values[:, i]),
            )
    _send_state(rec, layout.palm(root), t, [r.X_current for r in records])
    hands = [r.X_human if r.hand is not None else None for r in records]
    _send_state(rec, layout.hand(root), t, hands)
    _send_state(rec, layout.goal(root), t, [r.X_goal for r in records])
    _send_belief(rec, root, t, records)
    if scene is not None:
        _send_scene(rec, root, t, records, scene.frames)
    # One line per tick (a time holds one row of an entity): its task events and notes.
    ev_t, ev = [], []
    for k, r in enumerate(records):
        items = [f"{e.kind.value}:{e.detail}" if e.detail else e.kind.value for e in r.plant.events]
        items += list(r.notes)
        if items:
            ev_t.append(t[k])
            ev.append("; ".join(items))
    _send_texts(rec, layout.events(root), ev_t, ev)
    st_t, st = [], []
    last: tuple[Status, str] | None = None
    for k, r in enumerate(records):
        now = (r.status, r.reason)
        if now != last:
            st_t.append(t[k])
            st.append(r.status.value if not r.reason else f"{r.status.value}: {r.reason}")
            last = now
    _send_texts(rec, layout.status(root), st_t, st)


def _send_belief(
    rec: rr.RecordingStream, root: str, t: Array, records: Sequence[TickRecord]
) -> None:
    """A robot not told its goal: its belief in each candidate and its confidence per
    dimension and joint, one row per tick (NaN where it had none: told, or not a candidate
    then); nothing for a run without a belief."""
    if all(r.belief is None for r in records):
        return
    names: list[str] = []
    for r in records:
        for n in r.belief.names if r.belief is not None else ():
            if n not in names:
                names.append(n)
    dims = records[0].dims
    T = len(records)
    p = np.full((T, len(names)), np.nan)
    c = np.full((T, len(dims) + 1), np.nan)
    for k, r in enumerate(records):
        b = r.belief
        if b is not None:
            p[k, [names.index(n) for n in b.names]] = b.probability
            c[k] = [*b.confidence, b.confidence_joint]
    for j, n in enumerate(names):
        rec.send_columns(
            layout.belief(root, n), indexes=_time(t), columns=rr.Scalars.columns(scalars=p[:, j])
        )
    for i, d in enumerate((*dims, "joint")):
        rec.send_columns(
            layout.confidence(root, d),
            indexes=_time(t),
            columns=rr.Scalars.columns(scalars=c[:, i]),
        )


def _send_state(
    rec: rr.RecordingStream, path: str, t: Array, states: Sequence[HandState | None]
) -> None:
    keep = [k for k, X in enumerate(states) if X is not None]
    if not keep:
        return
    p = np.stack([states[k].position for k in keep])  # type: ignore[union-attr]
    R = np.stack([states[k].rotation for k in keep])  # type: ignore[union-attr]
    _send_poses(rec, path, t[keep], p, R)


def _send_scene(
    rec: rr.RecordingStream,
    root: str,
    t: Array,
    records: Sequence[TickRecord],
    frames: tuple[str, ...],
) -> None:
    """The scene's frame poses (`PlantStep.scene`, rows in `frames` order), where exported."""
    keep = [
        k
        for k, r in enumerate(records)
        if r.plant.scene is not None and r.plant.scene.positions_m.shape[0] == len(frames)
    ]
    if not keep:
        return
    pos = np.stack([records[k].plant.scene.positions_m for k in keep])  # type: ignore[union-attr]
    wxyz = np.stack([records[k].plant.scene.wxyz for k in keep])  # type: ignore[union-attr]
    q = np.concatenate([wxyz[..., 1:], wxyz[..., :1]], axis=-1)
    for i, frame in enumerate(frames):
        rec.send_columns(
            layout.scene_frame(root, frame),
            indexes=_time(t[keep]),
            columns=rr.Transform3D.columns(translation=pos[:, i], quaternion=q[:, i]),
        )


def log_scene_geometry(rec: rr.RecordingStream, root: str, geometry: SceneGeometry) -> None:
    """The scene's shapes, static, each below its frame's entity (`layout.scene_frame`)."""
    rec.log("", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for i, v in enumerate(geometry.visuals):
        path = f"{layout.scene_frame(root, v.frame)}/visual_{i}"
        w, x, y, z = v.wxyz_frame_visual
        rec.log(
            path,
            rr.Transform3D(translation=v.p_frame_visual_m, quaternion=_quat([x, y, z, w])),
            static=True,
        )
        shape = _shape(v)
        if shape is not None:
            rec.log(path, shape, static=True)


def _shape(v: VisualGeometry) -> Any:
    rgba = [round(255 * c) for c in v.rgba]
    if v.kind == "box":
        return rr.Boxes3D(half_sizes=[[s / 2 for s in v.size_m]], colors=[rgba], fill_mode="solid")
    if v.kind == "sphere":
        return rr.Ellipsoids3D(radii=[v.size_m[0]], colors=[rgba], fill_mode="solid")
    if v.kind == "cylinder":
        # Centred, along the local z axis (as in PyBullet).
        r, length = v.size_m[0], v.size_m[1]
        return rr.Cylinders3D(lengths=[length], radii=[r], colors=[rgba], fill_mode="solid")
    if v.kind == "capsule":
        # Rerun's capsule starts at its translation; PyBullet's is centred (local z axis).
        r, length = v.size_m[0], v.size_m[1]
        return rr.Capsules3D(
            lengths=[length], radii=[r], translations=[[0.0, 0.0, -length / 2]], colors=[rgba]
        )
    if v.kind == "mesh" and v.mesh_path:
        return rr.Asset3D(path=v.mesh_path, albedo_factor=rgba)
    return None  # a plane: the floor is not drawn


def log_true_goals(rec: rr.RecordingStream, plant_meta: dict[str, Any]) -> None:
    """The task's true pick and place poses, static (`layout.goal_true`)."""
    for name in ("pick", "place"):
        g = plant_meta.get(f"{name}_true")  # {"p": [3], "R": [9] row-major} (KitchenTask)
        if not isinstance(g, dict) or "p" not in g or "R" not in g:
            continue
        p = np.asarray(g["p"], dtype=np.float64)
        R = np.asarray(g["R"], dtype=np.float64).reshape(3, 3)
        rec.log(
            layout.goal_true(name),
            rr.Transform3D(translation=p, quaternion=_quat(xyzw(R))),
            rr.TransformAxes3D(axis_length=AXIS_LENGTH_M),
            static=True,
        )


@dataclass(frozen=True)
class CameraFrame:
    """One camera frame for the recording: when [s on the run's timeline] and its JPEG."""

    t_s: float
    jpeg: bytes


def log_camera(rec: rr.RecordingStream, frames: Iterable[CameraFrame]) -> int:
    """Camera frames as JPEG images (`layout.CAMERA_IMAGE`); returns how many."""
    fs = list(frames)
    if fs:
        rec.send_columns(
            layout.CAMERA_IMAGE,
            indexes=_time([f.t_s for f in fs]),
            columns=rr.EncodedImage.columns(blob=[f.jpeg for f in fs], media_type=[JPEG] * len(fs)),
        )
    return len(fs)


def log_landmarks(rec: rr.RecordingStream, records: Sequence[TickRecord], t0_s: float) -> int:
    """The tracked 2-D landmarks of the ticks' hand samples, in pixels over the camera image
    (`layout.CAMERA_LANDMARKS`), one set per frame; returns how many."""
    t, pts, seen = [], [], set()
    for r in records:
        s = r.hand.sample if r.hand is not None else None
        if s is None or not s.detected or s.landmarks_image is None or s.seq in seen:
            continue
        seen.add(s.seq)
        xy = np.asarray(s.landmarks_image, dtype=np.float64)[:, :2]
        scale = np.array([max(s.width_px, 1), max(s.height_px, 1)], dtype=np.float64)
        t.append(s.t_capture_s - t0_s)
        pts.append(xy * scale)
    if pts:
        rec.send_columns(
            layout.CAMERA_LANDMARKS,
            indexes=_time(t),
            columns=rr.Points2D.columns(positions=np.concatenate(pts)).partition(
                [len(p) for p in pts]
            ),
        )
    return len(pts)


def blueprint(roots: Sequence[str], camera: bool = False) -> Any:
    """The layout a recording opens with: the scene of the last run (the robot, the hand,
    the goals), the camera when there is one, and per-dimension plots that put the runs
    side by side ("alpha/yaw" of S against DS), with the events beside them."""
    import rerun.blueprint as rrb

    scene_root = roots[-1]
    scene = rrb.Spatial3DView(
        name=f"scene ({scene_root})",
        origin="/",
        contents=[
            f"/{scene_root}/scene/**",
            f"/{layout.palm(scene_root)}",
            f"/{layout.hand(scene_root)}",
            f"/{layout.goal(scene_root)}",
            "/goal_true/**",
        ],
    )
    left: list[Any] = [scene]
    if camera:
        left.append(rrb.Spatial2DView(name="camera", origin="/camera"))
    plots = [
        rrb.TimeSeriesView(
            name=f"{q}/{dim}",
            origin="/",
            contents=[f"/{layout.series(r, q, dim)}" for r in roots],
        )
        for q, dim in (("alpha", "yaw"), ("alpha", "x"), ("alpha", "y"), ("B", "yaw"))
    ]
    texts = rrb.TextLogView(
        name="events",
        origin="/",
        contents=[f"/{p(r)}" for r in roots for p in (layout.events, layout.status)],
    )
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*left), rrb.Vertical(*plots, texts), column_shares=[3, 2]),
        rrb.TimePanel(state="expanded"),
        collapse_panels=False,
    )
