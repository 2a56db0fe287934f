"""The 3-D part of the browser view: bodies, goal frames, the operator's ghost hand, a trail.

The viewer never imports PyBullet (docs/CONVENTIONS.md): the loop hands it the robot's scene
description once (each body's or link's visual shapes: primitive sizes or mesh files, scale,
colour, offset in the body/link frame) and every snapshot carries the per-tick world poses
(positions [m] and wxyz quaternions in the robot base frame, which is viser's world frame).
This module turns both into viser nodes:

    /w/<i>                    one node per body/link (i: its index), moved every tick
    /w/<i>/<k>                its visual shapes, placed once, never updated
    /goal/pick, /goal/place   goal frames (the active goal is drawn larger)
    /ghost                    the operator's commanded hand X_human, translucent
    /robot_hand               the robot hand from X_current when no scene description came
    /trail                    the output trajectory, newest segments opaque, oldest faded

The descriptions are read by duck typing (`visual_shapes`, `frame_poses`), so this module
depends on no robot type: objects or dicts with the field names below, or their common
aliases, are accepted.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import HandState

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

# Colours (RGB 0-255): the operator is blue, the robot orange, everywhere in the view.
HUMAN_RGB = (47, 127, 216)
ROBOT_RGB = (232, 112, 42)
GOAL_RGB = (40, 170, 90)

# The ghost hand's proportions (metres), close to the robot hand's (robot/hand_urdf.py).
PALM_SIZE_M = (0.090, 0.075, 0.030)
FINGER_SIZE_M = (0.018, 0.016, 0.085)
# (name, position of the finger base in the palm frame [m], flex direction)
GHOST_FINGERS: tuple[tuple[str, tuple[float, float, float], float], ...] = (
    ("thumb", (0.0, 0.024, 0.0), -1.0),
    ("index", (0.024, -0.024, 0.0), 1.0),
    ("middle", (0.0, -0.024, 0.0), 1.0),
    ("ring", (-0.024, -0.024, 0.0), 1.0),
)
FINGER_CLOSED_RAD = 1.3  # finger flexion at openness 0 (about the palm's x axis)


@dataclass(frozen=True)
class VisualShape:
    """One visual primitive or mesh attached to a moving frame (a body or a link).

    Attributes:
        frame: name of the body/link whose pose moves this shape.
        kind: "box", "sphere", "cylinder", "capsule" or "mesh".
        size_m: box: full extents (3,); sphere: (radius,); cylinder/capsule: (radius,
            length) along the local z axis; mesh: unused.
        rgba: colour, components in [0, 1].
        p_frame_shape_m: position of the shape in the frame [m].
        wxyz_frame_shape: orientation of the shape in the frame (unit quaternion, wxyz).
        mesh_path: mesh file (OBJ/STL/...) for kind "mesh".
        mesh_scale: per-axis scale of the mesh.
    """

    frame: str
    kind: str
    size_m: tuple[float, ...]
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    p_frame_shape_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wxyz_frame_shape: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    mesh_path: str | None = None
    mesh_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class FramePoses:
    """World poses of the moving frames at one tick.

    Attributes:
        names: frame names, matching `VisualShape.frame`.
        positions_m: (N, 3) positions in the base frame [m].
        wxyz: (N, 4) unit quaternions, wxyz.
    """

    names: tuple[str, ...]
    positions_m: Array
    wxyz: Array


# ----------------------------------------------------------------------------- adapters


def _get(obj: Any, *names: str, default: Any = None) -> Any:
    """The first attribute or key of `obj` among `names` (aliases), else `default`."""
    for n in names:
        if isinstance(obj, Mapping):
            if n in obj:
                return obj[n]
        elif hasattr(obj, n):
            return getattr(obj, n)
    return default


def _tuple(x: Any, n: int | None = None) -> tuple[float, ...]:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if n is not None and a.size != n:
        raise ValueError(f"expected {n} values, got {a.size}")
    return tuple(float(v) for v in a)


def quat_wxyz_from_matrix(R: Array) -> Array:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    qa = np.asarray(q, dtype=np.float64)
    qa /= np.linalg.norm(qa)
    return -qa if qa[0] < 0.0 else qa


def _shape_from(item: Any, frame: str | None = None) -> VisualShape:
    kind = str(_get(item, "kind", "type", "shape", "geometry", default="box")).lower()
    if kind == "ball":
        kind = "sphere"
    mesh = _get(item, "mesh_path", "filename", "mesh", "path")
    if mesh is not None:
        kind = "mesh"
    size = _get(item, "size_m", "size", "dimensions", "extents_m", "half_extents_m")
    if size is None:
        radius = _get(item, "radius_m", "radius")
        length = _get(item, "length_m", "length", "height_m", "height", default=0.0)
        size = () if radius is None else (radius, length)
    elif _get(item, "half_extents_m") is not None and _get(item, "size_m", "size") is None:
        size = 2.0 * np.asarray(size, dtype=np.float64)
    p = _get(
        item,
        "p_frame_shape_m",
        "p_link_visual_m",
        "p_body_part_m",
        "position_m",
        "offset_m",
        "position",
        default=(0.0, 0.0, 0.0),
    )
    q = _get(
        item, "wxyz_frame_shape", "wxyz_frame_visual", "wxyz_link_visual", "wxyz", default=None
    )
    if q is None:
        R = _get(item, "R_frame_shape", "R_link_visual", "R_body_part", "rotation", default=None)
        q = (1.0, 0.0, 0.0, 0.0) if R is None else quat_wxyz_from_matrix(np.asarray(R))
    scale = _get(item, "mesh_scale", "scale", default=(1.0, 1.0, 1.0))
    scale_t = _tuple(scale)
    if len(scale_t) == 1:
        scale_t = scale_t * 3
    rgba = _tuple(_get(item, "rgba", "color", "colour", default=(0.7, 0.7, 0.7, 1.0)))
    if len(rgba) == 3:
        rgba = (*rgba, 1.0)
    name = frame if frame is not None else _get(item, "frame", "link", "body", "name")
    if name is None:
        raise ValueError("a visual shape needs the name of its frame (frame/link/body)")
    return VisualShape(
        frame=str(name),
        kind=kind,
        size_m=_tuple(size) if len(size) else (),
        rgba=(rgba[0], rgba[1], rgba[2], rgba[3]),
        p_frame_shape_m=(*_tuple(p, 3),),  # type: ignore[arg-type]
        wxyz_frame_shape=(*_tuple(q, 4),),  # type: ignore[arg-type]
        mesh_path=None if mesh is None else str(mesh),
        mesh_scale=(scale_t[0], scale_t[1], scale_t[2]),
    )


def frame_order(description: Any) -> tuple[tuple[str, ...], tuple[bool, ...]]:
    """The description's frame names in pose-row order and which never move ((), () if
    it does not say)."""
    frames = _get(description, "frames") if description is not None else None
    if frames is None or isinstance(description, (list, tuple)):
        return (), ()
    names = tuple(str(f) for f in frames)
    static = _get(description, "static", default=None)
    flags = tuple(bool(b) for b in static) if static is not None else (False,) * len(names)
    return names, flags if len(flags) == len(names) else (False,) * len(names)


def visual_shapes(description: Any) -> tuple[VisualShape, ...]:
    """Read a scene description into visual shapes.

    Accepted: a sequence of `VisualShape` (or of objects/dicts with a `frame`/`link`/`body`
    name and the shape fields); a mapping frame name -> sequence of shapes; or an object
    whose `visuals`/`shapes`/`bodies`/`links` attribute is one of those.

    Raises:
        ValueError: when the description cannot be read.
    """
    if description is None:
        return ()
    inner = _get(description, "visuals", "shapes", "bodies", "links")
    if inner is not None and not isinstance(description, (list, tuple)):
        return visual_shapes(inner)
    if isinstance(description, Mapping):
        out: list[VisualShape] = []
        for frame, items in description.items():
            parts = _get(items, "visuals", "shapes", "parts", default=items)
            if isinstance(parts, Mapping) or not isinstance(parts, Iterable):
                parts = [parts]
            out.extend(
                s if isinstance(s, VisualShape) else _shape_from(s, str(frame)) for s in parts
            )
        return tuple(out)
    out = []
    for item in description:
        if isinstance(item, VisualShape):
            out.append(item)
            continue
        parts = _get(item, "visuals", "shapes", "parts")
        if parts is not None:
            frame = str(_get(item, "frame", "link", "body", "name"))
            out.extend(_shape_from(p, frame) for p in parts)
        else:
            out.append(_shape_from(item))
    return tuple(out)


def frame_poses(scene: Any, frames: Sequence[str] = ()) -> FramePoses | None:
    """Read a snapshot's `scene` field (per-tick poses) into `FramePoses`, or None.

    Accepted: `FramePoses`; an object/dict with `positions_m`/`positions` (N, 3) and
    `wxyz`/`quaternions_wxyz` (N, 4), rows named by its `names`/`frames` or, without them,
    by `frames` (the static description's frame order); a mapping name -> (position, wxyz)
    or name -> object with position and wxyz.
    """
    if scene is None:
        return None
    if isinstance(scene, FramePoses):
        return scene
    names = _get(scene, "names", "frames")
    if names is None and frames and _get(scene, "positions_m", "positions") is not None:
        names = frames
    if names is not None:
        pos = _get(scene, "positions_m", "positions", "p_m")
        quat = _get(scene, "wxyz", "quaternions_wxyz", "orientations_wxyz")
        return FramePoses(
            tuple(str(n) for n in names),
            np.asarray(pos, dtype=np.float64).reshape(-1, 3),
            np.asarray(quat, dtype=np.float64).reshape(-1, 4),
        )
    poses = _get(scene, "poses", default=scene)
    if isinstance(poses, Mapping):
        keys, ps, qs = [], [], []
        for k, v in poses.items():
            if isinstance(v, (tuple, list)) and len(v) == 2:
                p, q = v
            else:
                p = _get(v, "position_m", "position", "p_m")
                q = _get(v, "wxyz", "quaternion_wxyz")
            keys.append(str(k))
            ps.append(_tuple(p, 3))
            qs.append(_tuple(q, 4))
        return FramePoses(tuple(keys), np.asarray(ps).reshape(-1, 3), np.asarray(qs).reshape(-1, 4))
    return None


# ----------------------------------------------------------------------------- drawing


def _rgb(rgba: Sequence[float]) -> tuple[int, int, int]:
    return (
        round(255 * float(rgba[0])),
        round(255 * float(rgba[1])),
        round(255 * float(rgba[2])),
    )


def _finger_pose(
    base: tuple[float, float, float], sign: float, openness: float
) -> tuple[Array, Array]:
    """Centre and wxyz of a ghost finger in the palm frame: flexed about x by openness."""
    # Rotation about the palm's x axis by theta; the finger's axis (0, 0, 1) goes to
    # (0, -sin theta, cos theta): fingers (sign +1) close towards +y, the thumb towards -y,
    # as the robot hand's joints do (robot/hand_urdf.py).
    theta = -sign * FINGER_CLOSED_RAD * (1.0 - float(np.clip(openness, 0.0, 1.0)))
    half = FINGER_SIZE_M[2] / 2
    centre = np.array(
        [base[0], base[1] - half * math.sin(theta), PALM_SIZE_M[2] / 2 + half * math.cos(theta)]
    )
    wxyz = np.array([math.cos(theta / 2), math.sin(theta / 2), 0.0, 0.0])
    return centre, wxyz


POSITION_DEADBAND_M = 2e-4  # pose changes below these are not sent to the browsers
QUATERNION_DEADBAND = 5e-4


class ChangedRows:
    """Which frames moved since they were last sent (vectorised; static frames once).

    Args:
        static: names of frames that never move: sent once, then skipped.
    """

    def __init__(self, static: set[str] | frozenset[str] = frozenset()) -> None:
        self._static = static
        self._names: tuple[str, ...] = ()
        self._P = np.zeros((0, 3))
        self._Q = np.zeros((0, 4))
        self._skip = np.zeros(0, dtype=bool)

    def rows(self, poses: FramePoses) -> list[int]:
        """Indices of the rows of `poses` to send now (and remember them as sent)."""
        P = np.asarray(poses.positions_m, dtype=np.float64)
        Q = np.asarray(poses.wxyz, dtype=np.float64)
        if poses.names != self._names:
            self._names = poses.names
            self._P = np.full_like(P, np.nan)
            self._Q = np.full_like(Q, np.nan)
            self._skip = np.zeros(len(P), dtype=bool)
        moved = ~(np.abs(P - self._P).max(axis=1) <= POSITION_DEADBAND_M) | ~(
            np.abs(Q - self._Q).max(axis=1) <= QUATERNION_DEADBAND
        )
        moved &= ~self._skip & np.isfinite(P).all(axis=1) & np.isfinite(Q).all(axis=1)
        idx = np.flatnonzero(moved)
        self._P[idx], self._Q[idx] = P[idx], Q[idx]
        for i in idx:
            if self._names[i] in self._static:
                self._skip[i] = True
        return [int(i) for i in idx]


def _moved(last: Array | None, new: Array, tol: float) -> bool:
    return last is None or not bool(np.abs(new - last).max() <= tol)


class HandProxy:
    """A palm box and four finger boxes, posed from a `HandState` (ghost or robot)."""

    def __init__(self, scene: Any, name: str, rgb: tuple[int, int, int], opacity: float) -> None:
        self.root = scene.add_frame(name, show_axes=True, axes_length=0.06, axes_radius=0.003)
        scene.add_box(
            f"{name}/palm", color=rgb, dimensions=PALM_SIZE_M, opacity=opacity, cast_shadow=False
        )
        self.fingers = []
        for fname, base, sign in GHOST_FINGERS:
            c, q = _finger_pose(base, sign, 1.0)
            self.fingers.append(
                scene.add_box(
                    f"{name}/{fname}",
                    color=rgb,
                    dimensions=FINGER_SIZE_M,
                    opacity=opacity,
                    position=c,
                    wxyz=q,
                    cast_shadow=False,
                )
            )
        self._openness = np.ones(len(GHOST_FINGERS))
        self._p: Array | None = None
        self._q: Array | None = None

    def update(self, X: HandState | None) -> None:
        """Pose the proxy (hide it when `X` is None)."""
        if X is None or not np.isfinite(X.position).all():
            if self.root.visible:
                self.root.visible = False
            return
        if not self.root.visible:
            self.root.visible = True
        p = np.asarray(X.position, dtype=np.float64)
        q = quat_wxyz_from_matrix(X.rotation)
        if _moved(self._p, p, POSITION_DEADBAND_M) or _moved(self._q, q, QUATERNION_DEADBAND):
            self._p, self._q = p, q
            self.root.position = p
            self.root.wxyz = q
        g = np.asarray(X.openness, dtype=np.float64)
        if g.shape == self._openness.shape and np.abs(g - self._openness).max() > 0.01:
            self._openness = g.copy()
            for (_, base, sign), handle, gi in zip(GHOST_FINGERS, self.fingers, g):
                c, q = _finger_pose(base, sign, float(gi))
                handle.position = c
                handle.wxyz = q


class Trail:
    """A fading line through the robot's recent palm positions (newest opaque)."""

    def __init__(self, scene: Any, name: str, length: int, min_step_m: float = 0.002) -> None:
        self._scene = scene
        self._name = name
        self._points: deque[Array] = deque(maxlen=length)
        self._min_step_m = min_step_m
        self._handle: Any = None
        self._dirty = False

    def push(self, p_m: Array) -> None:
        """Append a position when it moved more than `min_step_m` from the last one."""
        p = np.asarray(p_m, dtype=np.float64)
        if not np.isfinite(p).all():
            return
        if self._points and np.linalg.norm(p - self._points[-1]) < self._min_step_m:
            return
        self._points.append(p.copy())
        self._dirty = True

    def clear(self) -> None:
        self._points.clear()
        self._dirty = True

    def draw(self) -> None:
        """Send the trail when it changed (segments coloured from faint to orange)."""
        if not self._dirty:
            return
        self._dirty = False
        n = len(self._points)
        if n < 2:
            if self._handle is not None:
                self._handle.visible = False
            return
        pts = np.asarray(self._points)
        segs = np.stack([pts[:-1], pts[1:]], axis=1).astype(np.float32)  # (n-1, 2, 3)
        fade = np.linspace(0.15, 1.0, n - 1, dtype=np.float32)[:, None]
        bg = np.array([245, 235, 225], dtype=np.float32)
        fg = np.array(ROBOT_RGB, dtype=np.float32)
        col = (bg + (fg - bg) * fade).astype(np.uint8)
        colors = np.repeat(col[:, None, :], 2, axis=1)
        if self._handle is None:
            self._handle = self._scene.add_line_segments(
                self._name, points=segs, colors=colors, thickness=4.0, thickness_units="screen"
            )
        else:
            self._handle.points = segs
            self._handle.colors = colors
            self._handle.visible = True


class SceneView:
    """All 3-D nodes of the view; `update` is called from the viewer thread only.

    Args:
        scene: the server's `viser.SceneApi`.
        shapes: visual shapes of the robot and the task objects (may be empty: the robot
            hand is then drawn as a proxy at `X_current`).
        trail_len: number of trail points kept.
    """

    def __init__(
        self,
        scene: Any,
        shapes: Sequence[VisualShape],
        trail_len: int = 150,
        frames: Sequence[str] = (),
        static: Sequence[bool] = (),
    ) -> None:
        self._scene = scene
        self._frame_order = tuple(frames)
        self._static = {f for f, s in zip(frames, static) if s}
        self._changed = ChangedRows(self._static)
        self._warned = False
        scene.set_up_direction("+z")
        scene.add_grid(
            "/grid",
            width=2.0,
            height=2.0,
            cell_size=0.1,
            section_size=0.5,
            position=(0.5, 0.0, -0.001),
        )
        # Short node names: every pose update carries the name (/w/<frame index>).
        self.frames: dict[str, Any] = {}
        nodes: dict[str, str] = {}
        for k, s in enumerate(shapes):
            if s.frame not in self.frames:
                nodes[s.frame] = f"/w/{len(nodes)}"
                self.frames[s.frame] = scene.add_frame(nodes[s.frame], show_axes=False)
            self._add_shape(f"{nodes[s.frame]}/{k}", s)
        self.goals = {
            name: scene.add_frame(
                f"/goal/{name}",
                axes_length=0.08,
                axes_radius=0.004,
                origin_color=GOAL_RGB,
                visible=False,
            )
            for name in ("pick", "place")
        }
        self._goal_label = scene.add_label("/goal_label", "goal", visible=False)
        self._active_goal = ""
        self._goal_p: dict[str, Array] = {}
        self._goal_q: dict[str, Array] = {}
        self.ghost = HandProxy(scene, "/ghost", HUMAN_RGB, opacity=0.35)
        self.robot_hand = None if self.frames else HandProxy(scene, "/robot_hand", ROBOT_RGB, 1.0)
        self.trail = Trail(scene, "/trail", trail_len)
        self._last_tick = -1

    def _add_shape(self, name: str, s: VisualShape) -> None:
        rgb = _rgb(s.rgba)
        opacity = None if s.rgba[3] >= 0.999 else float(s.rgba[3])
        kw: dict[str, Any] = {"position": s.p_frame_shape_m, "wxyz": s.wxyz_frame_shape}
        if s.kind == "box" and len(s.size_m) == 3:
            self._scene.add_box(name, color=rgb, dimensions=s.size_m, opacity=opacity, **kw)
        elif s.kind == "sphere" and len(s.size_m) >= 1:
            self._scene.add_icosphere(
                name, radius=s.size_m[0], color=rgb, opacity=opacity, subdivisions=2, **kw
            )
        elif s.kind in ("cylinder", "capsule") and len(s.size_m) >= 2:
            self._scene.add_cylinder(
                name,
                radius=s.size_m[0],
                height=s.size_m[1],
                color=rgb,
                opacity=opacity,
                radial_segments=16,
                **kw,
            )
        elif s.kind == "mesh" and s.mesh_path:
            self._add_mesh(name, s, rgb, opacity, kw)
        else:
            log.debug("viewer: skipped shape %s of %s (%s)", s.kind, s.frame, s.size_m)

    def _add_mesh(
        self,
        name: str,
        s: VisualShape,
        rgb: tuple[int, int, int],
        opacity: float | None,
        kw: dict[str, Any],
    ) -> None:
        path = Path(str(s.mesh_path))
        if not path.is_file():
            log.warning("viewer: mesh %s not found; %s drawn without it", path, s.frame)
            return
        import trimesh  # viser's own dependency; loaded only when a mesh is drawn

        mesh: Any = trimesh.load(str(path), force="mesh", process=False)
        vertices = np.asarray(mesh.vertices, dtype=np.float32) * np.asarray(
            s.mesh_scale, dtype=np.float32
        )
        self._scene.add_mesh_simple(
            name,
            vertices=vertices,
            faces=np.asarray(mesh.faces, dtype=np.uint32),
            color=rgb,
            opacity=opacity,
            flat_shading=False,
            **kw,
        )

    def update(self, snap: Any) -> None:
        """Move everything to the snapshot's tick (call inside `server.atomic()`)."""
        poses = frame_poses(snap.scene, self._frame_order)
        if poses is not None:
            if len(poses.names) == len(poses.positions_m) == len(poses.wxyz):
                for i in self._changed.rows(poses):
                    h = self.frames.get(poses.names[i])
                    if h is not None:
                        h.position = poses.positions_m[i]
                        h.wxyz = poses.wxyz[i]
            elif not self._warned:
                self._warned = True
                log.warning(
                    "viewer: %d pose rows for %d frames; the scene is not moved",
                    len(poses.positions_m),
                    len(poses.names),
                )
        if self.robot_hand is not None:
            self.robot_hand.update(snap.X_current)
        self.ghost.update(snap.X_human)
        self._update_goal(snap)
        if snap.tick < self._last_tick:  # the loop restarted: forget the old path
            self.trail.clear()
        self._last_tick = snap.tick
        self.trail.push(snap.X_current.position)

    def _update_goal(self, snap: Any) -> None:
        goal = snap.X_goal
        phase = str(snap.phase).lower()
        if phase == "done" or snap.outcome:  # no active goal; the frames stay put
            if self._active_goal:
                self._active_goal = ""
                self._goal_label.visible = False
            return
        name = "place" if "place" in phase else "pick"
        h = self.goals[name]
        if goal is None or not np.isfinite(goal.position).all():
            h.visible = False
            return
        p = np.asarray(goal.position, dtype=np.float64)
        q = quat_wxyz_from_matrix(goal.rotation)
        if not h.visible:
            h.visible = True
        moved = _moved(self._goal_p.get(name), p, POSITION_DEADBAND_M) or _moved(
            self._goal_q.get(name), q, QUATERNION_DEADBAND
        )
        if moved:
            self._goal_p[name], self._goal_q[name] = p, q
            h.position = p
            h.wxyz = q
            self._goal_label.position = p + np.array([0.0, 0.0, 0.06])
        if name != self._active_goal:  # the last known other goal stays, drawn smaller
            self._active_goal = name
            for k, g in self.goals.items():
                g.axes_length = 0.08 if k == name else 0.05
            self._goal_label.text = f"{name} goal"
            self._goal_label.visible = True
