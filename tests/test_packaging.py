"""Packaging: one `dsteleop` distribution with every app subpackage and the web assets as
package data, no top-level name collisions, headless cv2, an instant `--help`."""

from __future__ import annotations

import importlib.metadata as md
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
UV = REPO / ".tools" / "bin" / "uv"
#: Every app/ folder with an __init__.py (the tree is the truth; these must be among them).
APP_SUBPACKAGES = tuple(sorted(p.parent.name for p in (REPO / "app").glob("*/__init__.py")))
REQUIRED_SUBPACKAGES = {
    "bench", "cli", "inputs", "loop", "plants", "replay", "session", "study", "viewer",
}  # fmt: skip
WEB_ASSETS = ("dsteleop.css", "gauge_row.html", "status.html", "gauges_head.html")
#: The hand landmark model and the files beside it (tracking/models), as package data.
MODEL_FILES = ("hand_landmarker.task", "hand_landmarker.task.sha256", "LICENSE", "NOTICE")
SHARED_VIDEO = REPO.parent / "shared" / "data" / "videos" / "open_hand_wave_landscape.mp4"
#: Blocks every socket in the process it runs in (prepended to the offline probes).
NO_SOCKETS = """
import socket
def _refuse(*args, **kwargs):
    raise OSError("network use in an offline test")
socket.socket.connect = socket.socket.connect_ex = _refuse
socket.create_connection = socket.getaddrinfo = _refuse
"""


def test_the_package_list_names_every_app_subpackage() -> None:
    """pyproject lists the packages by hand: every app/ subpackage must be in that list."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    listed = set(
        tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    assert REQUIRED_SUBPACKAGES <= set(APP_SUBPACKAGES)
    missing = {f"dsteleop.app.{n}" for n in APP_SUBPACKAGES} - listed
    assert not missing, f"not in [tool.setuptools] packages: {sorted(missing)}"
    assert "dsteleop.web_assets" in listed
    assert "dsteleop.tracking.models" in listed
    for name in WEB_ASSETS:
        assert (REPO / "web_assets" / name).is_file(), name


def test_cv2_comes_from_the_headless_build_only() -> None:
    import cv2

    dist_files = {str(f) for f in md.distribution("opencv-python-headless").files or []}
    assert "cv2/__init__.py" in dist_files
    assert Path(cv2.__file__).parent.name == "cv2"
    for other in ("opencv-contrib-python", "opencv-python", "opencv-contrib-python-headless"):
        with pytest.raises(md.PackageNotFoundError):
            md.distribution(other)


def test_mediapipe_is_the_pinned_release() -> None:
    """The release pyproject.toml pins exactly (and whose metadata it restates)."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert "mediapipe==1.2.3" in project["project"]["dependencies"]
    assert md.version("mediapipe") == "1.2.3"
    (override,) = project["tool"]["uv"]["dependency-metadata"]
    assert (override["name"], override["version"]) == ("mediapipe", "1.2.3")


def test_mediapipe_has_the_tasks_hand_landmarker() -> None:
    """The tracker's one code path (tracking/detector.py): the Tasks API; its model comes
    from this package, not from the mediapipe wheel."""
    import importlib

    vision = importlib.import_module("mediapipe.tasks.python.vision")
    for name in ("HandLandmarker", "HandLandmarkerOptions", "RunningMode"):
        assert hasattr(vision, name), name
    assert hasattr(importlib.import_module("mediapipe.tasks.python"), "BaseOptions")


#: Prints the `dsteleop --help` and `dsteleop run --help` texts, then the heavy modules they
#: loaded ("loaded: a,b"; empty when none).
HELP_PROBE = """
import contextlib, sys
from dsteleop.app.cli.main import build_parser, main
assert 'bench' in build_parser().format_help()
for argv in (['--help'], ['run', '--help']):
    with contextlib.suppress(SystemExit):
        main(argv)
heavy = ('mediapipe', 'pybullet', 'viser', 'cv2')
print('loaded:' + ','.join(m for m in heavy if m in sys.modules))
"""
BANNER = "pybullet build time"


def check_help_probe(python: str | Path, cwd: Path | None = None) -> None:
    """`dsteleop --help` and `dsteleop run --help` load no heavy module and print no banner."""
    out = subprocess.run(
        [str(python), "-c", HELP_PROBE], capture_output=True, text=True, cwd=cwd, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "loaded:", out.stdout
    assert "--max-seconds" in out.stdout  # run's own options were listed
    assert BANNER not in out.stdout + out.stderr


def test_cli_help_is_instant_and_imports_nothing_heavy() -> None:
    check_help_probe(sys.executable)


def test_unknown_command_and_bad_bench_group_are_one_line_errors() -> None:
    exe = [sys.executable, "-m", "dsteleop.app.cli.main"]
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
    names = set(zipfile.ZipFile(wheel).namelist())
    tops = {n.split("/")[0] for n in names}
    assert tops == {"dsteleop", wheel.name.split("-py3")[0] + ".dist-info"}
    # Every module of every app subpackage (app/cli, app/loop, app/session, ...) is in it.
    app_modules = {
        "dsteleop/app/" + p.relative_to(REPO / "app").as_posix()
        for p in (REPO / "app").rglob("*.py")
        if "__pycache__" not in p.parts
    }
    assert {f"dsteleop/app/{sub}/__init__.py" for sub in APP_SUBPACKAGES} <= app_modules
    assert app_modules <= names, sorted(app_modules - names)
    # The browser view's stylesheet and templates, as package data.
    assert {f"dsteleop/web_assets/{a}" for a in WEB_ASSETS} <= names
    # The shipped robot descriptions and the hand's URDF they mount (docs/robots.md).
    robots = {f"dsteleop/robot/robots/{p.name}" for p in (REPO / "robot/robots").glob("*.toml")}
    assert {"dsteleop/robot/robots/iiwa.toml", "dsteleop/robot/robots/panda.toml"} <= robots
    assert robots | {"dsteleop/robot/assets/dsteleop_hand.urdf"} <= names
    # The hand landmark model, byte for byte, with its digest, license and notice.
    model_files = {f"dsteleop/tracking/models/{m}" for m in MODEL_FILES}
    assert model_files <= names, sorted(model_files - names)
    for m in MODEL_FILES:
        member = zipfile.ZipFile(wheel).read(f"dsteleop/tracking/models/{m}")
        assert member == (REPO / "tracking" / "models" / m).read_bytes(), m

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
        "import importlib.util, dsteleop, dsteleop.arbitration as a, dsteleop.app.cli.main\n"
        "assert '/site-packages/dsteleop/' in a.__file__, a.__file__\n"
        "assert all(importlib.util.find_spec(n) is None"
        " for n in ('app', 'robot', 'tracking', 'arbitration'))\n"
        f"assert all(importlib.util.find_spec('dsteleop.app.' + n) for n in {APP_SUBPACKAGES!r})\n"
        "from importlib import resources\n"
        "assets = resources.files('dsteleop.web_assets')\n"
        "assert '/site-packages/dsteleop/web_assets' in str(assets), assets\n"
        f"for name in {WEB_ASSETS!r}:\n"
        "    assert assets.joinpath(name).read_text(encoding='utf-8').strip(), name\n"
        "import cv2, mediapipe; print(cv2.__version__)\n"
    )
    run = subprocess.run(
        [str(py), "-c", code], cwd=tmp_path, capture_output=True, text=True, env=env
    )
    assert run.returncode == 0, run.stderr
    # The installed command: its help is instant (no PyBullet banner, nothing heavy loaded).
    check_help_probe(py, cwd=tmp_path)
    for argv in (["--help"], ["run", "--help"]):
        help_out = subprocess.run(
            [str(venv / "bin" / "dsteleop"), *argv], cwd=tmp_path, capture_output=True, text=True
        )
        assert help_out.returncode == 0, help_out.stderr
        assert ("bench" if argv == ["--help"] else "--max-seconds") in help_out.stdout
        assert BANNER not in help_out.stdout + help_out.stderr
    check_model_offline(py, venv, tmp_path, env)
    shutil.rmtree(venv)


def offline(argv: list[str]) -> list[str]:
    """`argv` in a network namespace of its own (no interface but loopback) where the
    machine allows it (`unshare -rn`); the probes also block sockets themselves."""
    unshare = shutil.which("unshare")
    if unshare and subprocess.run([unshare, "-rn", "true"], capture_output=True).returncode == 0:
        return [unshare, "-rn", *argv]
    return argv


def check_model_offline(py: Path, venv: Path, cwd: Path, env: dict[str, str]) -> None:
    """The installed wheel loads its own hand model (digest checked) and MediaPipe runs it,
    with no network: on a real video frame when the test data is there, else a blank one."""
    probe = NO_SOCKETS + (
        "import numpy as np\n"
        "from dsteleop.tracking import DetectorConfig, make_detector\n"
        "import dsteleop.tracking.models as m\n"
        "assert '/site-packages/dsteleop/tracking/models/' in m.__file__, m.__file__\n"
        "assert len(m.hand_model_bytes()) == 7_819_105\n"
        "d = make_detector(DetectorConfig())\n"
        "print(d.detect(np.zeros((240, 320, 3), np.uint8), 0.0))\n"
    )
    run = subprocess.run(
        offline([str(py), "-c", probe]), cwd=cwd, capture_output=True, text=True, env=env
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip().splitlines()[-1] == "[]"
    if not SHARED_VIDEO.is_file():
        return
    out = cwd / "track.jsonl"
    track = NO_SOCKETS + (
        "import sys\n"
        "from dsteleop.app.cli.main import main\n"
        f"sys.exit(main(['track', {str(SHARED_VIDEO)!r}, '--out', {str(out)!r},"
        " '--max-frames', '20']))\n"
    )
    run = subprocess.run(
        offline([str(py), "-c", track]), cwd=cwd, capture_output=True, text=True, env=env
    )
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    assert summary["frames"] == 20 and summary["detection_rate"] >= 0.9, summary
