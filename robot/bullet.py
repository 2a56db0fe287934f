"""PyBullet, imported once and without its banner.

PyBullet's C module writes a build banner to stderr when it is imported ("pybullet build
time: ..."), which clutters every command's log and a user's terminal. The import below sends
file descriptor 2 to /dev/null for its duration; everything in `robot/` imports PyBullet
from here.
"""

from __future__ import annotations

import importlib
import os
import sys
from typing import Any


def _quiet_import(name: str) -> Any:
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            return importlib.import_module(name)
    finally:
        os.dup2(saved, 2)
        os.close(saved)


pb: Any = _quiet_import("pybullet")
