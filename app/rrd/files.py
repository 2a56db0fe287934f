"""Writing `.rrd` files: one stream per file, and merging parts into one file.

A replay writes each (session, mode) run from its own worker process into its own part file
(recording id = the session, so the modes of a session share one recording), then merges the
parts into the user's FILE.rrd with Rerun's own `rrd merge` (the `rerun` command-line tool
that ships in the rerun-sdk wheel: no network, no viewer).
"""

from __future__ import annotations

import logging
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import rerun as rr

from dsteleop.app.rrd.layout import APPLICATION_ID
from dsteleop.errors import InputError

log = logging.getLogger(__name__)


def file_recording(path: Path, recording_id: str) -> rr.RecordingStream:
    """A recording stream that writes `path` (its folder must exist)."""
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    rec.save(path)
    return rec


def merge(parts: Sequence[Path], out: Path) -> None:
    """Merge `.rrd` parts into `out`; recordings with the same id become one.

    Raises:
        InputError: the merge failed (one line, with Rerun's last message).
    """
    if not parts:
        raise InputError(f"{out}: nothing to write")
    cmd = [sys.executable, "-m", "rerun_cli", "rrd", "merge", *map(str, parts), "-o", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0 or not out.is_file():
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise InputError(f"{out}: could not write the Rerun recording ({last})")
    log.debug("merged %d parts into %s", len(parts), out)
