#!/usr/bin/env bash
# dsteleop developer entry point: sets up the locked environment, then starts the app or runs
# every check. Needs only python3 (3.10-3.13) on PATH; everything else comes from PyPI.
#
#   ./dev.sh start [dsteleop serve options]   set up, then serve the app (demo without a webcam)
#   ./dev.sh test  [pytest options]           set up, then ruff, mypy and the whole test suite
#   ./dev.sh sync                             set up only
#
# Which Python: DSTELEOP_PYTHON (a command or path) when set, else the first of python3.11,
# python3.10, python3, python3.13, python3.12 that is CPython 3.10-3.13 (3.11 and 3.10 first:
# every package has a wheel for them; on 3.12 and 3.13 pybullet is built from source). The
# environment is DSTELEOP_VENV (default .venv), built from the same uv.lock whatever the Python.
set -euo pipefail
cd "$(dirname "$0")"

UV_VERSION="0.13.9"            # the installer; uv.lock pins everything it installs
TOOLS=".tools"                 # private virtualenv that holds uv itself
VENV="${DSTELEOP_VENV:-.venv}"
export UV_PYTHON_DOWNLOADS=never UV_PROJECT_ENVIRONMENT="$VENV"
SUPPORTED="3.10, 3.11, 3.12 or 3.13"

die() { echo "dev.sh: $*" >&2; exit 1; }

supported() {
    "$1" -c 'import sys; sys.exit(not (sys.implementation.name == "cpython" and (3, 10) <= sys.version_info[:2] <= (3, 13)))' 2>/dev/null
}

find_python() {
    if [ -n "${DSTELEOP_PYTHON:-}" ]; then
        supported "$DSTELEOP_PYTHON" && { echo "$DSTELEOP_PYTHON"; return 0; }
        die "DSTELEOP_PYTHON=$DSTELEOP_PYTHON is not CPython $SUPPORTED"
    fi
    for py in python3.11 python3.10 python3 python3.13 python3.12; do
        if command -v "$py" >/dev/null 2>&1 && supported "$py"; then
            echo "$py"; return 0
        fi
    done
    return 1
}

# Debian/Ubuntu packages, when we are root and have apt-get; else say what to install.
apt_install() {
    local why="$1"; shift
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "dev.sh: installing $* (apt-get): $why" >&2
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
    else
        die "$why: install $* (sudo apt-get install $*)"
    fi
}

# pybullet publishes wheels up to CPython 3.11 (uv.lock lists them); on a newer Python uv
# builds it from its source archive, which needs a C++ compiler and Python's headers. Say so
# before a ~10 minute build, and make sure both are there.
prepare_pybullet_build() {
    local py="$1" tag version
    tag=$("$py" -c 'import sys; print("cp%d%d" % sys.version_info[:2])')
    version=$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
    grep -q "pybullet-[0-9.]*-$tag-" uv.lock && return 0
    # Built already (this environment, or uv's cache, which keeps the built wheel).
    if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c 'import importlib.metadata as m; m.version("pybullet")' >/dev/null 2>&1; then
        return 0
    fi
    echo "dev.sh: pybullet has no wheel for CPython $version: uv builds it from source, once" >&2
    echo "dev.sh:   (about 10 minutes on two cores; later installs reuse the wheel in uv's cache)" >&2
    if ! command -v g++ >/dev/null 2>&1 && ! command -v c++ >/dev/null 2>&1; then
        apt_install "building pybullet needs a C++ compiler" g++
    fi
    local include
    include=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
    if [ ! -f "$include/Python.h" ]; then
        local dev
        dev=$("$py" -c 'import sys; print("python%d.%d-dev" % sys.version_info[:2])')
        apt_install "building pybullet needs Python's headers ($include/Python.h)" "$dev"
    fi
}

ensure_uv() {
    if [ -x "$TOOLS/bin/uv" ] && [ "$("$TOOLS/bin/uv" --version | cut -d' ' -f2)" = "$UV_VERSION" ]; then
        return 0
    fi
    local py
    py=$(find_python) || die "CPython $SUPPORTED is needed (python3 on PATH)"
    if ! "$py" -m venv --clear "$TOOLS" >/dev/null 2>&1; then
        # Debian and Ubuntu ship venv/ensurepip separately.
        apt_install "$py cannot create a virtualenv" python3-venv
        "$py" -m venv --clear "$TOOLS" || die "could not create $TOOLS with $py -m venv"
    fi
    "$TOOLS/bin/python" -m pip install --quiet --disable-pip-version-check "uv==$UV_VERSION" ||
        die "could not install uv $UV_VERSION from PyPI"
}

sync() {
    ensure_uv
    local py
    py=$(find_python) || die "CPython $SUPPORTED is needed"
    prepare_pybullet_build "$py"
    # --compile-bytecode: every command starts without compiling its libraries again where
    # Python cannot cache bytecode (PYTHONDONTWRITEBYTECODE=1, as containers often set; ~3 s
    # of each `dsteleop sim` run here went to compiling matplotlib and scipy).
    # The interpreter's own path, not a launcher's (a pyenv shim): uv compares it with the
    # one .venv was made with, and on a mismatch deletes and rebuilds .venv, every run.
    local interpreter
    interpreter=$("$py" -c 'import sys; print(sys.executable)')
    "$TOOLS/bin/uv" sync --locked --compile-bytecode --python "$interpreter" --quiet
    # The arbitration kernel and the arm's IK are compiled by numba; compile them now (~1 min
    # the first time, then loaded from the cache in under a second), not in a session.
    "$VENV/bin/python" -c 'from dsteleop.arbitration.arbiters import compile_kernels as a
from dsteleop.robot.kinematics import compile_kernels as r
a(); r()'
}

cmd="${1:-}"
[ $# -gt 0 ] && shift
case "$cmd" in
    sync)
        sync ;;
    start)
        sync
        if "$VENV/bin/python" -c 'import sys; from dsteleop.app.cli.main import COMMANDS; sys.exit("serve" not in COMMANDS)'; then
            exec "$VENV/bin/dsteleop" serve "$@"
        fi
        echo "dev.sh: the browser app (dsteleop serve) is not built yet; here is what the CLI offers:" >&2
        exec "$VENV/bin/dsteleop" --help ;;
    test)
        sync
        "$TOOLS/bin/uv" pip check --python "$VENV/bin/python"
        "$VENV/bin/ruff" check .
        "$VENV/bin/ruff" format --check .
        # Against the environment's own Python and stubs (numpy's differ between 3.10-3.11's
        # release and 3.12+'s): pyproject.toml's python_version is the oldest supported.
        "$VENV/bin/mypy" --python-version "$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
        status=0
        "$VENV/bin/python" -m pytest "$@" || status=$?
        # pytest exits 5 when it collected nothing: that is a failure here, never a pass.
        [ "$status" = 5 ] && die "pytest collected no tests"
        exit "$status" ;;
    *)
        sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'
        exit 2 ;;
esac
