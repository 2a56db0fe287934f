"""Sessions as LeRobot v3.0 datasets: export, live recording, reading back (docs/datasets.md).

Importing this package loads nothing heavy (the command line checks an output folder with
it before anything is opened); its modules import pyarrow and PyAV.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from dsteleop.errors import InputError

#: Where `--record-lerobot DIR` keeps its sessions when the command records none itself:
#: inside the dataset folder, hidden (LeRobot reads only meta/, data/ and videos/).
SESSIONS = ".dsteleop-sessions"
#: The file that makes a folder a dataset (`layout.INFO`; written after a first episode).
_INFO = Path("meta") / "info.json"


def check_out_dir(out: Path) -> None:
    """`out` must not exist or be an empty folder, and its parent must be writable.

    A folder that holds a `SESSIONS` folder but no dataset is what a `--record-lerobot` run
    leaves when it was killed before its first episode was written (its session's ticks
    are there, complete up to the kill): the error says so and what to do, rather than
    "not empty" about a folder that looks empty.

    Raises:
        InputError: it holds something, is a file, or cannot be created.
    """
    if out.exists():
        if not out.is_dir():
            raise InputError(f"output {out} exists and is not a folder")
        sessions = out / SESSIONS
        if sessions.is_dir() and not (out / _INFO).exists():
            n = sum(1 for p in sessions.iterdir() if p.is_dir())
            raise InputError(
                f"{out} holds no dataset, only {SESSIONS}/: the {n} session(s) of a "
                "--record-lerobot run that ended before its first episode was written, "
                f"kept there (replay and export read them); move {sessions} elsewhere (or "
                f"delete it) to reuse {out}, or choose a new or empty folder"
            )
        if (out / _INFO).exists():
            raise InputError(
                f"{out} holds a dataset already; a new dataset needs a new or empty folder"
            )
        if any(out.iterdir()):
            raise InputError(f"output folder {out} is not empty; choose a new or empty folder")
    parent = out.parent if out.parent != Path("") else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".dsteleop-write-test"):
            pass
    except OSError as exc:
        raise InputError(f"cannot write to {parent}: {exc.strerror or exc}") from None
