"""The 3-D part of the browser view: bodies, goal frames, the operator's ghost hand, a trail.

The viewer never imports PyBullet: the plant hands it the scene description once
(`robot.scene.SceneGeometry`: each frame's visual shapes, primitive sizes or mesh files,
scale, colour, offset in the frame) and every tick record carries the world poses
(`robot.scene.ScenePoses`: positions [m] and wxyz quaternions in the robot base frame, which
is viser's world frame, in the description's frame order). This module turns both into
viser nodes:

    /w/<i>                    one node per frame (i: its index), moved every tick
    /w/<i>/<k>                its visual shapes, placed once, never updated
    /goal/pick, /goal/place   goal frames (the active goal is drawn larger)
    /ghost                    the operator's commanded hand X_human, translucent
    /robot_hand               the robot hand from X_current when there is no description
    /trail                    the output trajectory, newest segments opaque, oldest faded
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.session.schema import TickRecord
from dsteleop.arbitration import HandState
from dsteleop.arbitration.se3 import quat_wxyz_from_matrix
from dsteleop.robot.scene import SceneGeometry, ScenePoses, VisualGeometry
from dsteleop.robot.task import Phase

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

    def rows(self, names: tuple[str, ...], poses: ScenePoses) -> list[int]:
        """Indices of the rows of `poses` (frames `names`) to send now, remembered as sent."""
        P = np.asarray(poses.positions_m, dtype=np.float64)
        Q = np.asarray(poses.wxyz, dtype=np.float64)
        if names != self._names:
            self._names = names
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
    """A palm box and four finger boxes, posed from a `HandState` (ghost or robot); a robot
    with other fingers than four (a gripper) shows their mean openness on all four."""

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
        if g.shape != self._openness.shape:  # another robot's fingers (a gripper: one):
            g = np.full(self._openness.shape, float(g.mean()) if g.size else 1.0)  # their mean
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
        geometry: the scene description, or None (the robot hand is then drawn as a proxy
            at `X_current`).
        trail_len: number of trail points kept.
    """

    def __init__(self, scene: Any, geometry: SceneGeometry | None, trail_len: int = 150) -> None:
        self._scene = scene
        self._frame_names: tuple[str, ...] = () if geometry is None else geometry.frames
        static = (
            set()
            if geometry is None
            else {f for f, s in zip(geometry.frames, geometry.static) if s}
        )
        self._changed = ChangedRows(static)
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
        if geometry is not None:
            nodes = {f: f"/w/{i}" for i, f in enumerate(geometry.frames)}
            for k, v in enumerate(geometry.visuals):
                if v.frame not in self.frames:
                    self.frames[v.frame] = scene.add_frame(nodes[v.frame], show_axes=False)
                self._add_shape(f"{nodes[v.frame]}/{k}", v)
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

    def _add_shape(self, name: str, v: VisualGeometry) -> None:
        rgb = _rgb(v.rgba)
        opacity = None if v.rgba[3] >= 0.999 else float(v.rgba[3])
        kw: dict[str, Any] = {"position": v.p_frame_visual_m, "wxyz": v.wxyz_frame_visual}
        if v.kind == "box" and len(v.size_m) == 3:
            self._scene.add_box(name, color=rgb, dimensions=v.size_m, opacity=opacity, **kw)
        elif v.kind == "sphere" and len(v.size_m) >= 1:
            self._scene.add_icosphere(
                name, radius=v.size_m[0], color=rgb, opacity=opacity, subdivisions=2, **kw
            )
        elif v.kind in ("cylinder", "capsule") and len(v.size_m) >= 2:
            self._scene.add_cylinder(
                name,
                radius=v.size_m[0],
                height=v.size_m[1],
                color=rgb,
                opacity=opacity,
                radial_segments=16,
                **kw,
            )
        elif v.kind == "mesh" and v.mesh_path:
            self._add_mesh(name, v, rgb, opacity, kw)
        else:
            log.debug("viewer: skipped shape %s of %s (%s)", v.kind, v.frame, v.size_m)

    def _add_mesh(
        self,
        name: str,
        v: VisualGeometry,
        rgb: tuple[int, int, int],
        opacity: float | None,
        kw: dict[str, Any],
    ) -> None:
        path = Path(str(v.mesh_path))
        if not path.is_file():
            log.warning("viewer: mesh %s not found; %s drawn without it", path, v.frame)
            return
        import trimesh  # a declared dependency (pyproject.toml); loaded only for meshes

        try:
            mesh: Any = trimesh.load(str(path), force="mesh", process=False)
        except (ImportError, ValueError, OSError) as exc:
            # e.g. a COLLADA (.dae) mesh without pycollada (the `robots` extra installs it)
            log.warning(
                "viewer: mesh %s cannot be read (%s); %s drawn without it", path, exc, v.frame
            )
            return
        vertices = np.asarray(mesh.vertices, dtype=np.float32) * np.asarray(
            v.mesh_scale, dtype=np.float32
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

    def update(self, record: TickRecord, X_human: HandState | None) -> None:
        """Move everything to the record's tick (call inside `server.atomic()`).

        Args:
            record: the tick.
            X_human: the operator's hand to show (the last fresh one), or None.
        """
        poses = record.plant.scene
        if poses is not None:
            if len(self._frame_names) == len(poses.positions_m) == len(poses.wxyz):
                for i in self._changed.rows(self._frame_names, poses):
                    h = self.frames.get(self._frame_names[i])
                    if h is not None:
                        h.position = poses.positions_m[i]
                        h.wxyz = poses.wxyz[i]
            elif not self._warned:
                self._warned = True
                log.warning(
                    "viewer: %d pose rows for %d frames; the scene is not moved",
                    len(poses.positions_m),
                    len(self._frame_names),
                )
        if self.robot_hand is not None:
            self.robot_hand.update(record.X_current)
        self.ghost.update(X_human)
        self._update_goal(record)
        if record.k < self._last_tick:  # the loop restarted: forget the old path
            self.trail.clear()
        self._last_tick = record.k
        self.trail.push(record.X_current.position)

    def _update_goal(self, record: TickRecord) -> None:
        goal = record.X_goal
        if record.phase is Phase.DONE or record.outcome is not None or goal is None:
            if self._active_goal:  # no active goal; the frames stay put
                self._active_goal = ""
                self._goal_label.visible = False
            return
        name = "place" if record.phase is Phase.PLACE else "pick"
        h = self.goals[name]
        if not np.isfinite(goal.position).all():
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
