#!/usr/bin/env bash
# dsteleop developer entry point: sets up the locked environment, then starts the app or runs
# every check. Needs only python3 (3.10-3.12) on PATH; everything else comes from PyPI.
#
#   ./dev.sh start [dsteleop serve options]   set up, then serve the app (demo without a webcam)
#   ./dev.sh test  [pytest options]           set up, then ruff, mypy and the whole test suite
#   ./dev.sh sync                             set up only
set -euo pipefail
cd "$(dirname "$0")"

UV_VERSION="0.13.9"            # the installer; uv.lock pins everything it installs
TOOLS=".tools"                 # private virtualenv that holds uv itself
export UV_PYTHON_DOWNLOADS=never UV_PROJECT_ENVIRONMENT=.venv

die() { echo "dev.sh: $*" >&2; exit 1; }

find_python() {
    for py in python3.11 python3.12 python3.10 python3; do
        if command -v "$py" >/dev/null 2>&1 &&
            "$py" -c 'import sys; sys.exit(not (3, 10) <= sys.version_info[:2] <= (3, 12))' 2>/dev/null; then
            echo "$py"; return 0
        fi
    done
    return 1
}

ensure_uv() {
    if [ -x "$TOOLS/bin/uv" ] && [ "$("$TOOLS/bin/uv" --version | cut -d' ' -f2)" = "$UV_VERSION" ]; then
        return 0
    fi
    local py
    py=$(find_python) || die "Python 3.10, 3.11 or 3.12 is needed (python3 on PATH)"
    if ! "$py" -m venv --clear "$TOOLS" >/dev/null 2>&1; then
        # Debian and Ubuntu ship venv/ensurepip separately.
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
            echo "dev.sh: installing python3-venv (apt-get)" >&2
            apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv >/dev/null
            "$py" -m venv --clear "$TOOLS" || die "could not create $TOOLS with $py -m venv"
        else
            die "$py cannot create a virtualenv: install python3-venv (sudo apt-get install python3-venv)"
        fi
    fi
    "$TOOLS/bin/python" -m pip install --quiet --disable-pip-version-check "uv==$UV_VERSION" ||
        die "could not install uv $UV_VERSION from PyPI"
}

sync() {
    ensure_uv
    local py
    py=$(find_python) || die "Python 3.10, 3.11 or 3.12 is needed"
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
    .venv/bin/python -c 'from dsteleop.arbitration.arbiters import compile_kernels as a
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
        if .venv/bin/python -c 'import sys; from dsteleop.app.cli.main import COMMANDS; sys.exit("serve" not in COMMANDS)'; then
            exec .venv/bin/dsteleop serve "$@"
        fi
        echo "dev.sh: the browser app (dsteleop serve) is not built yet; here is what the CLI offers:" >&2
        exec .venv/bin/dsteleop --help ;;
    test)
        sync
        "$TOOLS/bin/uv" pip check --python .venv/bin/python
        .venv/bin/ruff check .
        .venv/bin/ruff format --check .
        .venv/bin/mypy
        status=0
        .venv/bin/python -m pytest "$@" || status=$?
        # pytest exits 5 when it collected nothing: that is a failure here, never a pass.
        [ "$status" = 5 ] && die "pytest collected no tests"
        exit "$status" ;;
    *)
        sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'
        exit 2 ;;
esac
