"""Native libraries' own stderr lines go through logging at debug level (app/cli/native_log.py).

A real `dsteleop track` on a real video loads MediaPipe (absl's `W0000 ...` lines, TFLite's
`INFO: Created ...`) and a real `dsteleop run` loads PyBullet: none of their own lines reach
stderr unless `-v` asks for debug output, and then as `dsteleop.native` log records.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dsteleop.app.cli.native_log import is_native_line

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
NATIVE_STARTS = (
    "W0000",
    "I0000",
    "E0000",
    "INFO: Created",
    "INFO: [",
    "WARNING: All log",
    "WARNING: Logging before",
    "pybullet build",
)


def test_native_line_shapes() -> None:
    for line in (
        "W0000 00:00:1796178255.381955    1672 inference_feedback_manager.cc:114] Feedback",
        "INFO: Created TensorFlow Lite XNNPACK delegate for CPU.",
        "WARNING: All log messages before absl::InitializeLog() is called are written to STDERR",
        "INFO: [accelerator_registry.cc:43] DestroyAccelerator: ptr=0x7ff5, name=CpuAccelerator",
        "WARNING: Logging before InitGoogle() is written to STDERR",
        "[mov,mp4,m4a,3gp,3g2,mj2 @ 0x55df907192c0] moov atom not found",
        "[ WARN:0@0.019] global cap.cpp:779 open VIDEOIO(CV_IMAGES): raised OpenCV exception:",
        "pybullet build time: Nov 28 2023 23:45:17",
    ):
        assert is_native_line(line), line
    for line in (
        "2026-12-02 02:27:50,475 INFO dsteleop.app.cli.track: track: ...",
        "dsteleop track: error: video not found: x.mp4",
        "Traceback (most recent call last):",
    ):
        assert not is_native_line(line), line


@pytest.mark.parametrize("verbose", [False, True], ids=["quiet", "verbose"])
def test_native_lines_only_as_debug_records(
    shared_data: Path, tmp_path: Path, verbose: bool
) -> None:
    video = shared_data / "videos" / "webcam_two_hands.mp4"
    if not video.is_file():
        pytest.skip(f"test video not found: {video}")
    flags = ["-v"] if verbose else []
    track = [*CLI, *flags, "track", str(video), "--out", str(tmp_path / "t.jsonl")]
    done = subprocess.run(
        [*track, "--max-frames", "30"], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stderr.splitlines()
    assert not any(ln.startswith(NATIVE_STARTS) for ln in lines), done.stderr
    native = [ln for ln in lines if "DEBUG dsteleop.native:" in ln]
    if verbose:  # MediaPipe spoke: its lines are there, as debug records
        assert any("W0000" in ln or "INFO: Created" in ln for ln in native), done.stderr
    else:
        assert not native
    run = subprocess.run(
        [*CLI, "run", "--source", "demo", "--max-seconds", "0.5"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "pybullet" not in run.stderr.lower()
    (line,) = run.stdout.strip().splitlines()  # stdout: the summary alone
    assert json.loads(line)["ticks"] == 15
