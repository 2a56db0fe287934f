"""The hand landmark model shipped inside dsteleop, and its integrity check.

`hand_landmarker.task` (MediaPipe's Hand Landmarker bundle: palm detector + landmark model,
Apache-2.0, see NOTICE and LICENSE beside it) is package data of this package; its sha256 is
in `hand_landmarker.task.sha256` (the `sha256sum` format). `hand_model_bytes()` reads the file
and checks it against that digest every time a detector is built: a missing, truncated or
replaced file is a `ModelFileError` (one line), never a model MediaPipe half-loads. Nothing
here downloads anything, and importing this module reads no file.
"""

from __future__ import annotations

import hashlib
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from dsteleop.errors import ModelFileError

if TYPE_CHECKING:
    from importlib.abc import Traversable

#: File name of the shipped model; its digest file is this name + ".sha256".
MODEL_FILE = "hand_landmarker.task"


def _read(folder: Traversable, name: str) -> bytes:
    ref = folder.joinpath(name)
    try:
        return ref.read_bytes()
    except OSError as exc:
        raise ModelFileError(
            f"the hand landmark model file {name} is missing from {folder}: reinstall dsteleop"
        ) from exc


def hand_model_bytes(folder: Path | None = None) -> bytes:
    """The shipped `hand_landmarker.task`, its sha256 checked.

    Args:
        folder: where the model and its digest file are (None: this package's data).

    Returns:
        The file's bytes (MediaPipe loads them from memory, so the bytes checked are the
        bytes loaded).

    Raises:
        ModelFileError: the file or its digest file is missing, or the digest does not match.
    """
    root: Traversable = resources.files(__name__) if folder is None else folder
    data = _read(root, MODEL_FILE)
    words = _read(root, MODEL_FILE + ".sha256").decode("ascii", errors="replace").split()
    want = words[0].lower() if words else ""
    if len(want) != 64:
        raise ModelFileError(f"{MODEL_FILE}.sha256 in {root} holds no sha256: reinstall dsteleop")
    got = hashlib.sha256(data).hexdigest()
    if got != want:
        raise ModelFileError(
            f"the hand landmark model {MODEL_FILE} in {root} is damaged ({len(data)} bytes, "
            f"sha256 {got[:12]}..., expected {want[:12]}...): reinstall dsteleop"
        )
    return data
