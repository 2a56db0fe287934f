"""Video files as a user brings them: turned by their container, or cut short.

Phone clips store their frames sideways with a rotation in the container; the sources turn
them upright, so that the person's up is image up and maps to robot up (checked with real
MediaPipe against the same frames never rotated). A file cut short says how many frames it
could read and fails unless `--allow-partial`.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dsteleop.app.cli.main import main
from dsteleop.tracking import HandTracker, VideoFileSource, iter_samples
from dsteleop.tracking.mapping import WorkspaceMapping
from tests.videos import Image, cut, read_frames, set_rotation, write_mp4

Array = np.ndarray[Any, np.dtype[np.float64]]

UPRIGHT = "videos/portrait_fingers_open_close.mp4"  # no rotation: fingers point up
PHONE = "videos/webcam_fist_thumb.mp4"  # stored sideways, the container turns it 90 deg


def _upright_frames(shared_data: Path, n: int) -> list[Image]:
    path = shared_data / UPRIGHT
    if not path.is_file():
        pytest.skip(f"test video not found: {path}")
    return [f[::2, ::2] for f in read_frames(path, n)]  # 270x480, still portrait


def _sideways_clip(tmp_path: Path, upright: list[Image], deg: int) -> Path:
    """The upright frames stored turned `deg` counter-clockwise, and a container that asks
    a player to turn them `deg` clockwise: what a phone writes."""
    import cv2

    back = {90: cv2.ROTATE_90_COUNTERCLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_CLOCKWISE}
    stored = [np.asarray(cv2.rotate(f, back[deg]), np.uint8) for f in upright]
    path = write_mp4(tmp_path / f"phone{deg}.mp4", stored)
    set_rotation(path, deg)
    return path


def _read_all(src: VideoFileSource) -> list[Image]:
    src.open()
    out = []
    try:
        while (f := src.read()) is not None:
            assert f.image is not None
            out.append(f.image)
    finally:
        src.close()
    return out


@pytest.mark.parametrize("deg", [90, 180, 270])
def test_a_rotated_clip_is_read_upright(tmp_path: Path, shared_data: Path, deg: int) -> None:
    upright = _upright_frames(shared_data, 12)
    clip = _sideways_clip(tmp_path, upright, deg)
    src = VideoFileSource(clip)
    frames = _read_all(src)
    assert src.container_rotation_deg == deg and src.rotation_deg == deg
    assert (src.width_px, src.height_px) == (upright[0].shape[1], upright[0].shape[0])
    assert len(frames) == len(upright)
    for got, want in zip(frames, upright):
        assert got.shape == want.shape
        assert np.abs(got.astype(int) - want.astype(int)).mean() < 4.0  # H.264 at crf 16
    # --rotate overrides the container: 0 gives the frames as stored.
    stored = _read_all(VideoFileSource(clip, rotate=0))
    assert stored[0].shape[:2] == (upright[0].shape[:2] if deg == 180 else upright[0].shape[1::-1])


def _hand_up_in_base(samples: list[Any], mapping: WorkspaceMapping) -> Array:
    """Per detected frame: the hand's up (wrist towards the fingers, the palm's x axis) in
    the robot base frame."""
    R_base_cam = mapping.config.R_base_cam
    return np.array([R_base_cam @ s.R_cam_palm[:, 0] for s in samples if s.detected])


def test_image_up_maps_to_robot_up_on_a_rotated_clip(tmp_path: Path, shared_data: Path) -> None:
    """Real MediaPipe on the rotated clip and on the same frames never rotated: the hand's
    up is robot +z in both, frame by frame; read as stored, it would be sideways."""
    upright = _upright_frames(shared_data, 45)
    clip = _sideways_clip(tmp_path, upright, 90)
    mapping = WorkspaceMapping()

    def track(path: Path, rotate: int | None = None) -> list[Any]:
        with HandTracker() as tracker:
            return [s for _, s in iter_samples(VideoFileSource(path, rotate=rotate), tracker)]

    reference = write_mp4(tmp_path / "upright.mp4", upright)
    up_ref = _hand_up_in_base(track(reference), mapping)
    up_rot = _hand_up_in_base(track(clip), mapping)
    up_stored = _hand_up_in_base(track(clip, rotate=0), mapping)
    assert len(up_ref) >= 35 and len(up_rot) >= 35
    # Fingers point up in the video: robot up (+z) within 35 degrees, most frames.
    assert np.median(up_ref[:, 2]) > 0.8 and np.median(up_rot[:, 2]) > 0.8
    n = min(len(up_ref), len(up_rot))
    angle = np.degrees(np.arccos(np.clip(np.sum(up_ref[:n] * up_rot[:n], axis=1), -1, 1)))
    assert np.median(angle) < 10.0, np.median(angle)
    # Read as stored (the bug), the hand's up is robot sideways (y), not up.
    assert abs(np.median(up_stored[:, 2])) < 0.3 and np.median(np.abs(up_stored[:, 1])) > 0.8


def _image_up_fraction(records: list[dict[str, Any]]) -> float:
    """Fraction of detected frames whose wrist -> middle-finger knuckle points image up
    (within 45 degrees; image y grows downwards)."""
    ups = []
    for r in records:
        if r["landmarks"]:
            lm = np.asarray(r["landmarks"])
            d = lm[9, :2] - lm[0, :2]
            ups.append(abs(np.degrees(np.arctan2(-d[1], d[0])) - 90.0) < 45.0)
    assert len(ups) > 100
    return float(np.mean(ups))


def test_track_on_a_rotated_phone_clip_gives_upright_landmarks(
    tmp_path: Path, shared_data: Path
) -> None:
    """`dsteleop track` on a phone clip stored sideways: the person holds the fist up by
    the face, so wrist -> knuckles is image up once the container's rotation is honoured."""
    video = shared_data / PHONE
    if not video.is_file():
        pytest.skip(f"test video not found: {video}")
    out = tmp_path / "t.jsonl"
    cmd = [sys.executable, "-m", "dsteleop.app.cli.main", "track", str(video), "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    records = [json.loads(ln) for ln in out.read_text().splitlines()]
    assert _image_up_fraction(records) > 0.9
    # No native library's own lines on stderr (MediaPipe's W0000, TFLite's INFO, FFmpeg's).
    assert not any(
        ln.startswith(("W0000", "INFO: Created", "WARNING: All log", "["))
        for ln in done.stderr.splitlines()
    ), done.stderr
    sideways = tmp_path / "s.jsonl"
    assert main(["track", str(video), "--out", str(sideways), "--rotate", "0"]) == 0
    assert _image_up_fraction([json.loads(ln) for ln in sideways.read_text().splitlines()]) < 0.1


# ----------------------------------------------------------------------------- cut short


def _truncated(tmp_path: Path, n: int = 90) -> tuple[Path, int]:
    """An index-first MP4 of `n` frames, cut to its first ~15 % of bytes."""
    frames = [np.random.default_rng(k).integers(0, 255, (96, 128, 3), np.uint8) for k in range(n)]
    whole = write_mp4(tmp_path / "whole.mp4", frames)
    return cut(whole, tmp_path / "cut.mp4", 0.15), n


def test_a_truncated_video_says_what_it_read(tmp_path: Path) -> None:
    path, n = _truncated(tmp_path)
    src = VideoFileSource(path)
    frames = _read_all(src)
    assert src.frame_count == n and 0 < len(frames) < n // 2
    assert src.partial and src.frames_read == len(frames)
    with pytest.raises(Exception, match=rf"read {len(frames)} of the {n} frames"):
        src.check_complete()
    whole = VideoFileSource(tmp_path / "whole.mp4")
    assert len(_read_all(whole)) == n and not whole.partial


def test_track_refuses_a_truncated_video_unless_allowed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, n = _truncated(tmp_path)
    out = tmp_path / "t.jsonl"
    assert main(["track", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"of the {n} frames it declares" in err[0], err
    read = len(out.read_text().splitlines())  # what it could read is kept
    assert 0 < read < n and f"read {read} of the {n}" in err[0]
    assert main(["track", str(path), "--out", str(out), "--allow-partial"]) == 0


@pytest.mark.parametrize("command", ["run", "replay"])
def test_run_and_replay_refuse_a_truncated_video(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    path, n = _truncated(tmp_path)
    if command == "run":
        argv = ["run", "--source", f"video:{path}", "--record", str(tmp_path / "s")]
    else:
        argv = ["replay", str(path), "--modes", "DS", "--no-plots", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"of the {n} frames it declares" in err, err
    if command == "run":  # the recording is kept, and closed
        meta = json.loads((tmp_path / "s" / "meta.json").read_text())
        assert meta["complete"] is True
    assert main([*argv[:-1], str(tmp_path / "again"), "--allow-partial"]) == 0
