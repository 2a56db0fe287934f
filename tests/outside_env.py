"""Virtual environments of their own for outside tools that tests run against dsteleop (never
dsteleop's environment, so nothing of ours leaks into the tool, nor the tool's pins into ours).

Each is made once with uv from the registry's wheels and cached by its requirements and
Python version under $XDG_CACHE_HOME/dsteleop-tests (~/.cache/dsteleop-tests). Making one
needs the package registry; running it afterwards does not. CI makes them before the tests
(`python -m tests.outside_env`, .ci/run), so there an install that fails fails CI instead of
skipping the test that needs it.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The outside ROS 2-over-Zenoh client (tests/test_link_ros2_client.py): zenoh-ros2-sdk, with
#: mcap-ros2-support as a second CDR implementation, and the eclipse-zenoh it runs on.
ROS2_CLIENT = ("zenoh-ros2-sdk==0.1.8", "mcap-ros2-support==0.6.0", "eclipse-zenoh==1.10.2")


class InstallError(Exception):
    """The requirements could not be installed from the package registry."""


def cache_dir() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "dsteleop-tests"


def python_with(requirements: tuple[str, ...]) -> Path:
    """The Python of a virtual environment that holds `requirements`, made on first use.

    Raises:
        InstallError: uv could not install them (the registry's last words in the message).
    """
    digest = hashlib.sha256("\n".join(requirements).encode()).hexdigest()[:12]
    venv = cache_dir() / f"venv-{digest}-py{sys.version_info[0]}{sys.version_info[1]}"
    py = venv / "bin" / "python"
    if py.is_file():
        return py
    uv = shutil.which("uv") or str(ROOT / ".tools" / "bin" / "uv")
    if shutil.which(uv) is None:
        raise InstallError("uv is not installed (./dev.sh sync installs it)")
    env = {**os.environ, "UV_PYTHON_DOWNLOADS": "never"}
    env.pop("VIRTUAL_ENV", None)
    tmp = venv.with_name(venv.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    base = getattr(sys, "_base_executable", sys.executable)
    r = subprocess.run(
        [uv, "venv", "--quiet", "--python", base, str(tmp)],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    if r.returncode != 0:
        raise AssertionError(f"uv venv failed: {r.stderr.strip()}")
    r = subprocess.run(
        [uv, "pip", "install", "--quiet", "--python", str(tmp / "bin" / "python"), *requirements],
        capture_output=True, text=True, env=env, timeout=900,
    )  # fmt: skip
    if r.returncode != 0:
        shutil.rmtree(tmp, ignore_errors=True)
        raise InstallError(" ".join(r.stderr.split())[-300:])
    shutil.rmtree(venv, ignore_errors=True)
    tmp.rename(venv)
    return py  # the venv's scripts name the folder they were made in: call its python


def main() -> int:
    """Make every outside environment the tests use; exit 1 with the reason if one fails."""
    try:
        print(f"outside_env: {' '.join(ROS2_CLIENT)}: {python_with(ROS2_CLIENT)}")
    except InstallError as exc:
        print(f"outside_env: cannot install {' '.join(ROS2_CLIENT)}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
