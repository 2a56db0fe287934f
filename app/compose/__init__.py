"""The composition root, below the command line: a loop built from a parsed, typed value.

    options   LoopOptions: what a loop is built from (the user's choices, checked)
    root      build(options) -> Built: the robot and the task, the hand input, the outputs,
              and the loop wired to them

The command line (`app/cli/`) parses its arguments into a `LoopOptions` and hands it down
here; benches and tests build the same value in code (`LoopOptions.of`). Nothing here
imports a command. `build` and `Built` load the robot's simulator (PyBullet) with them, so
they are imported on first use: a command's `--help` reads `options` only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from dsteleop.app.compose.options import LoopOptions

if TYPE_CHECKING:
    from dsteleop.app.compose.root import Built, build

__all__ = ["Built", "LoopOptions", "build"]


def __getattr__(name: str) -> Any:
    if name in ("Built", "build"):
        from dsteleop.app.compose import root

        return getattr(root, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
