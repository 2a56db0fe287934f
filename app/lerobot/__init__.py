"""Sessions as LeRobot v3.0 datasets: export, live recording, reading back (docs/datasets.md).

Importing this package loads nothing heavy (the command line checks an output folder with
it before anything is opened); its modules import pyarrow and PyAV.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from dsteleop.errors import InputError


def check_out_dir(out: Path) -> None:
    """`out` must not exist or be an empty folder, and its parent must be writable.

    Raises:
        InputError: it holds something, is a file, or cannot be created.
    """
    if out.exists():
        if not out.is_dir():
            raise InputError(f"output {out} exists and is not a folder")
        if any(out.iterdir()):
            raise InputError(f"output folder {out} is not empty; choose a new or empty folder")
    parent = out.parent if out.parent != Path("") else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".dsteleop-write-test"):
            pass
    except OSError as exc:
        raise InputError(f"cannot write to {parent}: {exc.strerror or exc}") from None
