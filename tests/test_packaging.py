"""Packaging: one `dsteleop` distribution, no top-level name collisions, headless cv2."""

from __future__ import annotations

import importlib.metadata as md
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
UV = REPO / ".tools" / "bin" / "uv"


def test_cv2_comes_from_the_headless_build_only() -> None:
    import cv2

    dist_files = {str(f) for f in md.distribution("opencv-python-headless").files or []}
    assert "cv2/__init__.py" in dist_files
    assert Path(cv2.__file__).parent.name == "cv2"
    for other in ("opencv-contrib-python", "opencv-python", "opencv-contrib-python-headless"):
        with pytest.raises(md.PackageNotFoundError):
            md.distribution(other)


def test_mediapipe_is_the_pinned_release_with_bundled_hand_models() -> None:
    import mediapipe as mp

    assert md.version("mediapipe") == "0.10.21"
    models = Path(mp.__file__).parent / "modules" / "hand_landmark"
    assert any(models.glob("hand_landmark_full.tflite")), "full hand model missing from the wheel"
    assert any(models.glob("hand_landmark_lite.tflite")), "lite hand model missing from the wheel"


def test_cli_help_is_instant_and_imports_nothing_heavy() -> None:
    code = (
        "import sys; from dsteleop.app import cli\n"
        "assert 'bench' in cli.build_parser().format_help()\n"
        "print(','.join(m for m in ('mediapipe', 'pybullet', 'viser', 'cv2')"
        " if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_unknown_command_and_bad_bench_group_are_one_line_errors() -> None:
    exe = [sys.executable, "-m", "dsteleop.app.cli"]
    r = subprocess.run([*exe, "nosuchcommand"], capture_output=True, text=True)
    assert r.returncode == 2 and "invalid choice" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([*exe, "bench", "--only", "nosuchgroup"], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "unknown bench group" in r.stderr


@pytest.mark.slow
def test_wheel_installs_in_a_fresh_environment_and_runs(tmp_path: Path) -> None:
    if not UV.exists():
        pytest.skip("uv is installed by ./dev.sh into .tools/; run the tests through ./dev.sh test")
    env = {**os.environ, "UV_PYTHON_DOWNLOADS": "never", "VIRTUAL_ENV": ""}
    env.pop("UV_PROJECT_ENVIRONMENT", None)
    dist = tmp_path / "dist"
    subprocess.run(
        [str(UV), "build", "--wheel", "-o", str(dist), str(REPO)],
        check=True,
        env=env,
        capture_output=True,
    )
    wheel = next(dist.glob("dsteleop-*.whl"))
    tops = {n.split("/")[0] for n in zipfile.ZipFile(wheel).namelist()}
    assert tops == {"dsteleop", wheel.name.split("-py3")[0] + ".dist-info"}

    # The locked dependency set, then the wheel alone, into a new virtualenv.
    req = tmp_path / "requirements.txt"
    export = subprocess.run(
        [
            str(UV),
            "export",
            "--frozen",
            "--no-dev",
            "--no-emit-project",
            "--no-hashes",
            "--project",
            str(REPO),
        ],
        check=True,
        env=env,
        capture_output=True,
        text=True,
    )
    req.write_text(export.stdout)
    venv = tmp_path / "venv"
    subprocess.run([str(UV), "venv", "-q", "-p", sys.executable, str(venv)], check=True, env=env)
    py = venv / "bin" / "python"
    subprocess.run(
        [str(UV), "pip", "install", "-q", "-p", str(py), "--no-deps", "-r", str(req)],
        check=True,
        env=env,
    )
    subprocess.run(
        [str(UV), "pip", "install", "-q", "-p", str(py), "--no-deps", str(wheel)],
        check=True,
        env=env,
    )

    code = (
        "import importlib.util, dsteleop, dsteleop.arbitration as a, dsteleop.app.cli\n"
        "assert '/site-packages/dsteleop/' in a.__file__, a.__file__\n"
        "assert all(importlib.util.find_spec(n) is None"
        " for n in ('app', 'robot', 'tracking', 'arbitration'))\n"
        "import cv2, mediapipe; print(cv2.__version__)\n"
    )
    run = subprocess.run(
        [str(py), "-c", code], cwd=tmp_path, capture_output=True, text=True, env=env
    )
    assert run.returncode == 0, run.stderr
    help_out = subprocess.run(
        [str(venv / "bin" / "dsteleop"), "--help"], cwd=tmp_path, capture_output=True, text=True
    )
    assert help_out.returncode == 0 and "bench" in help_out.stdout
    shutil.rmtree(venv)
