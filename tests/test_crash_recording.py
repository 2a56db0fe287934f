"""A camera recording survives `kill -9`: the video is readable up to its last frames and
`replay --retrack` tracks what is left.

A real `dsteleop run --realtime --record DIR --record-video` on a real hand video is killed
with SIGKILL mid-session; the video (fragmented MP4, every frame flushed) and its frame
index are then checked and re-tracked with real MediaPipe.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dsteleop.app.cli.main import main
from dsteleop.app.replay.video import frame_times
from dsteleop.tracking import VideoFileSource
from tests.videos import read_frames, write_mp4

pytestmark = pytest.mark.slow


def _count_frames(path: Path) -> int:
    src = VideoFileSource(path)
    src.open()
    n = 0
    try:
        while src.read() is not None:
            n += 1
    finally:
        src.close()
    return n


def test_kill_9_leaves_a_video_that_retracks(tmp_path: Path, shared_data: Path) -> None:
    video = shared_data / "videos" / "portrait_fingers_open_close.mp4"
    if not video.is_file():
        pytest.skip(f"test video not found: {video}")
    clip = write_mp4(tmp_path / "clip.mp4", [f[::2, ::2] for f in read_frames(video)])
    session = tmp_path / "session"
    argv = ["run", "--source", f"video:{clip}", "--realtime", "--record", str(session)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "dsteleop.app.cli.main", *argv, "--record-video"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    index = session / "frames.jsonl"
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and proc.poll() is None:
            if index.is_file() and len(index.read_bytes().splitlines()) >= 90:
                break
            time.sleep(0.1)
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    meta = json.loads((session / "meta.json").read_text())
    assert "complete" not in meta  # killed: never closed
    indexed = len(frame_times(index))
    assert indexed >= 90
    # Every indexed frame is in the video (each line is written after its frame).
    assert _count_frames(session / "video.mp4") >= indexed
    # And what is left re-tracks: every indexed frame, with the hand found in most.
    out = tmp_path / "out"
    assert main(["replay", str(session), "--retrack", "--modes", "DS", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    # The session was killed in its one episode: replayed, listed "incomplete", not counted.
    (replayed,) = metrics["episodes"]
    assert replayed["end"] == "incomplete" and not replayed["counted"]
    assert replayed["modes"]["DS"]["arbitrated_ticks"] >= 0.5 * indexed
