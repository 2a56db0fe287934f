"""What a viewer needs to draw the simulation without PyBullet: geometry once, poses per tick.

Every drawable frame has a name ("robot/palm", "table", "spoon", ...). `SceneGeometry` lists
each frame's visuals once: a primitive with its sizes, or a mesh file (an absolute path into
the installed `pybullet_data`, or into `robot/assets`) with its scale; colour as rgba in
[0, 1]; and the visual's fixed offset in its frame. `ScenePoses` gives every frame's world
(= robot base) pose for one tick as batched arrays aligned with `SceneGeometry.frames`:
positions [m] (N, 3) and quaternions (N, 4) in wxyz order (as viser). Both are plain
dataclasses of tuples/arrays: a viewer consumes them without importing pybullet.

Conventions: box sizes are full extents [m]; sphere (radius,); cylinder (radius, length)
along the visual's local z; plane () is the infinite plane z = 0 of its frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
VisualKind = Literal["box", "sphere", "cylinder", "capsule", "mesh", "plane"]


@dataclass(frozen=True)
class VisualGeometry:
    """One visual shape attached to a frame.

    Attributes:
        frame: name of the frame it moves with (an entry of `SceneGeometry.frames`).
        kind: primitive kind or "mesh".
        size_m: primitive sizes (see module docstring); () for meshes and planes.
        mesh_path: absolute path of the mesh file (.obj/.stl), or None.
        mesh_scale: per-axis mesh scale.
        rgba: colour, each in [0, 1].
        p_frame_visual_m: (3,) position of the visual in its frame [m].
        wxyz_frame_visual: (4,) orientation of the visual in its frame (w, x, y, z).
    """

    frame: str
    kind: VisualKind
    size_m: tuple[float, ...]
    mesh_path: str | None
    mesh_scale: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    p_frame_visual_m: tuple[float, float, float]
    wxyz_frame_visual: tuple[float, float, float, float]


@dataclass(frozen=True)
class SceneGeometry:
    """All frames and their visuals; sent to a viewer once per reset.

    Attributes:
        frames: frame names; `ScenePoses` rows follow this order.
        static: per frame, whether it never moves (table, holder, bin, floor, robot base).
        visuals: every visual shape.
        focus_m: the point a view looks at first [m]: the task's table between the holder
            and the bin, where the robot's placement stands it (`robot.placement`).
    """

    frames: tuple[str, ...]
    static: tuple[bool, ...]
    visuals: tuple[VisualGeometry, ...]
    focus_m: tuple[float, float, float] = (0.55, 0.0, 0.1)

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly form."""
        return {
            "frames": list(self.frames),
            "static": list(self.static),
            "visuals": [v.__dict__ | {"size_m": list(v.size_m)} for v in self.visuals],
            "focus_m": list(self.focus_m),
        }


@dataclass(frozen=True)
class ScenePoses:
    """World poses of every frame for one tick.

    Attributes:
        t_s: simulated time [s].
        positions_m: (N, 3) frame origins in the base frame [m].
        wxyz: (N, 4) frame orientations, quaternions (w, x, y, z).
    """

    t_s: float
    positions_m: Array
    wxyz: Array
