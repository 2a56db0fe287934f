"""Rerun recordings of replays: each (episode, mode) run into a part file, merged at the end.

    dsteleop replay SESSION... --modes S,DS --out DIR --rerun FILE.rrd

A part holds one run under its mode's root (`layout`), and, for the first mode of a session,
what the modes share: the true goals and the camera (the episode's frames from the session's
video, or the replayed video itself, JPEG; the tracked landmarks). Every part of an episode
carries the episode's name as its recording id, so `files.merge` makes one recording per
episode with the modes side by side on one timeline.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app.rrd import files
from dsteleop.app.rrd import log as rlog
from dsteleop.app.session.schema import TickRecord
from dsteleop.robot.scene import SceneGeometry

JPEG_QUALITY = 80


@dataclass(frozen=True)
class Camera:
    """Where a run's camera frames come from.

    Attributes:
        video: the video file.
        t_capture_s: the frames' capture times on the loop's clock (a session's frame
            index), or None: the video's own clock (a replayed video, whose ticks run on it).
        rotate: turn the frames [deg clockwise] (None: the container's own rotation), as
            the replay's tracking did.
    """

    video: Path
    t_capture_s: tuple[float, ...] | None = None
    rotate: int | None = None


def write_part(
    part: Path,
    recording_id: str,
    root: str,
    records: Sequence[TickRecord],
    scene: SceneGeometry | None,
    plant_meta: dict[str, Any] | None = None,
    camera: Camera | None = None,
    roots: Sequence[str] | None = None,
) -> None:
    """One run's part file (module docstring); shared entities when `plant_meta` or
    `camera` is given, and the recording's layout (`log.blueprint`) when `roots` names all
    the session's runs."""
    part.parent.mkdir(parents=True, exist_ok=True)
    rec = files.file_recording(part, recording_id)
    try:
        if roots is not None:
            rec.send_blueprint(rlog.blueprint(roots, camera=camera is not None))
        t0 = records[0].t_s if records else 0.0
        if scene is not None:
            rlog.log_scene_geometry(rec, root, scene)
        rlog.log_run(rec, root, records, t0, scene)
        if plant_meta is not None:
            rlog.log_true_goals(rec, plant_meta)
        if camera is not None and records:
            rlog.log_camera(rec, video_frames(camera, t0, records[-1].t_s - t0))
            rlog.log_landmarks(rec, records, t0)
        rec.flush()
    finally:
        rec.disconnect()


def video_frames(
    camera: Camera, t0_s: float, t_end_s: float = float("inf")
) -> Iterator[rlog.CameraFrame]:
    """The camera's readable frames captured within the run (0 to `t_end_s` on the run's
    timeline, a frame's length to spare), as JPEGs; a session's episode gets its own."""
    import cv2

    from dsteleop.tracking.sources import VideoFileSource

    src = VideoFileSource(camera.video, realtime=False, rotate=camera.rotate)
    src.open()
    try:
        k = 0
        while (frame := src.read()) is not None:
            if camera.t_capture_s is not None:
                if k >= len(camera.t_capture_s):
                    break
                t = camera.t_capture_s[k] - t0_s
            else:
                t = frame.t_capture_s - t0_s
            k += 1
            margin = 1.0 / src.fps
            if frame.image is None or not -margin <= t <= t_end_s + margin:
                continue
            ok, buf = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if ok:
                yield rlog.CameraFrame(float(t), buf.tobytes())
    finally:
        src.close()
