"""The composition root, below the command line: a loop built from a parsed, typed value.

    options   LoopOptions: what a loop is built from (the user's choices, checked)
    root      build(options) -> Built: the robot and the task, the hand input, the outputs,
              and the loop wired to them

The command line (`app/cli/`) parses its arguments into a `LoopOptions` and hands it down
here; benches and tests build the same value in code (`LoopOptions.of`). Nothing here
imports a command.
"""

from dsteleop.app.compose.options import LoopOptions
from dsteleop.app.compose.root import Built, build

__all__ = ["Built", "LoopOptions", "build"]
