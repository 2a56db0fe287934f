"""Where commands write: every output path is checked when the command line is read.

A path a command writes is checked before anything opens (a camera, the hand model, the
robot, a Ray cluster), so that a place that cannot be written is one line and exit code 2 at
the start, not a traceback when its first byte is written (a `--history` file is first
written at the first finished segment, mid-trial; a Rerun file when its logger starts; `track
--out` once the model has loaded). Each option that names an output takes one of these as its
argparse `type`, which marks it beside the option's definition:

    output_file           a file written or replaced: --history, --rerun, track --out and
                          --preview. Not a folder; its folder exists; a hidden temporary file
                          can be made there (the atomic writes' temporary file and rename);
                          an existing file opens for appending (nothing is written to it)
    output_dir            a folder created (with its parents) or written into: --record,
                          --record-lerobot, the --out of replay, sim, tune and export. Not a
                          file; a hidden temporary file can be made in the folder, or, when it
                          does not exist yet, in its nearest existing parent

`cli.main` runs `check_outputs` over the command's parser once the arguments are parsed and
before the command runs, so a new output option is checked by giving it `type=output_file`
(or `output_dir`), nothing more.

The checks are probes (a file made and removed at once), not permission bits: they give the
same answer for root, on a read-only file system and in a folder of someone else's. A check
creates nothing. A command makes its output folder with `created_dir`, which removes the
folders it created itself when the command fails and leaves them empty (never a folder that
existed before, never one with anything in it).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from dsteleop.errors import InputError

#: The prefix of the probe files (hidden; removed as soon as made).
PROBE_PREFIX = ".dsteleop-write-test-"


def unwritable(folder: Path) -> str | None:
    """Why no file can be made in the existing folder `folder` (None: one can)."""
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=PROBE_PREFIX):
            return None
    except OSError as exc:
        return exc.strerror or str(exc)


def check_output_file(path: Path, option: str) -> Path:
    """`path` can be written (created or replaced) as a file (module docstring).

    Raises:
        InputError: one line naming `option` and saying why not.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} must name a file, got the folder {path}")
    folder = path.parent
    if not folder.is_dir():
        raise InputError(f"{option}: no such folder: {folder}")
    why = unwritable(folder)
    if why is not None:
        raise InputError(f"{option}: cannot write to {path} ({folder}: {why})")
    if path.exists():
        if not path.is_file():  # a device or a pipe: a write would replace or block on it
            raise InputError(f"{option} must name a regular file, got {path}")
        try:
            with path.open("ab"):
                pass
        except OSError as exc:
            raise InputError(f"{option}: cannot write to {path} ({exc.strerror or exc})") from None
    return path


def check_output_dir(path: Path, option: str) -> Path:
    """`path` is a folder that can be written into, or one that can be created (module
    docstring); nothing is created.

    Raises:
        InputError: one line naming `option` and saying why not.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} must name a folder, got the file {path}")
    existing = path
    while not existing.is_dir():
        if existing.exists() or existing.parent == existing:  # a file on the way, or the root
            raise InputError(f"{option}: cannot write to {path} ({existing} is not a folder)")
        existing = existing.parent
    why = unwritable(existing)
    if why is not None:
        if existing != path:
            why = f"{existing}: {why}"
        raise InputError(f"{option}: cannot write to {path} ({why})")
    return path


class OutputPath:
    """The argparse `type` of an option that names an output (module docstring): converts
    the text to a `Path` and marks the option, so that `check_outputs` finds it."""

    def __call__(self, text: str) -> Path:
        return Path(text)

    def check(self, path: Path, option: str) -> Path:
        return check_output_file(path, option)


class OutputDir(OutputPath):
    """The argparse `type` of an option that names an output folder."""

    def check(self, path: Path, option: str) -> Path:
        return check_output_dir(path, option)


#: `type=` of an option naming a file the command writes.
output_file = OutputPath()
#: `type=` of an option naming a folder the command writes into.
output_dir = OutputDir()


def check_outputs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Check every output path given to `parser`'s options (those whose `type` is an
    `OutputPath`): the command line's one check, before the command runs (`cli.main`).

    Raises:
        InputError: the first that cannot be written (one line naming its option).
    """
    for action in parser._actions:
        if not isinstance(action.type, OutputPath) or not action.option_strings:
            continue
        value = getattr(args, action.dest, None)
        for path in value if isinstance(value, list) else [value]:
            if path is not None:
                action.type.check(Path(path), action.option_strings[-1])


@contextmanager
def created_dir(path: Path, option: str = "--out") -> Iterator[Path]:
    """Make the output folder `path` (and its missing parents) for the block; when the block
    fails (any exception, Ctrl-C too), remove the folders made here that are still empty,
    deepest first: a failed command leaves no empty output folder behind, and nothing that
    existed before or holds anything is ever removed.

    Raises:
        InputError: the folder cannot be made or written (one line).
    """
    path = Path(path)
    made: list[Path] = []
    p = path
    while not p.exists() and p.parent != p:
        made.append(p)
        p = p.parent
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(made)
        raise InputError(f"{option}: cannot write to {path} ({exc.strerror or exc})") from None
    why = unwritable(path)
    if why is not None:
        _remove_empty(made)
        raise InputError(f"{option}: cannot write to {path} ({why})")
    try:
        yield path
    except BaseException:
        _remove_empty(made)
        raise


def _remove_empty(folders: list[Path]) -> None:
    """Remove each folder (deepest first) while it is empty; stop at the first that is not."""
    for d in folders:
        try:
            os.rmdir(d)
        except FileNotFoundError:
            continue
        except OSError:  # not empty (or no longer ours to remove): leave it and its parents
            break
