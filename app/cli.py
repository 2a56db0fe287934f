"""The `dsteleop` command: a thin dispatcher over sub-command modules.

Each sub-command lives in its own module with `add_arguments(parser)` and `run(args) -> int`;
modules are imported only when their command runs, so `dsteleop --help` stays instant and
never loads MediaPipe, PyBullet or Viser. A `DsteleopError` anywhere becomes one line on
stderr and exit code 2; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from dsteleop import __version__
from dsteleop.errors import DsteleopError

# name -> (module, one-line help). Add a command by adding a line here.
COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("dsteleop.app.bench", "run benchmarks and print one JSON object"),
}

log = logging.getLogger("dsteleop")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        # argparse's own errors: one line and exit code 2, like every other bad input.
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="dsteleop",
        description="Telemanipulation from one bare hand with dimension-specific shared autonomy.",
    )
    parser.add_argument("--version", action="version", version=f"dsteleop {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (_module, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, description=help_text)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # Parse the command name first, then let its module add its own options.
    pre, _ = parser.parse_known_args(argv)
    if pre.command is None:
        parser.print_help()
        return 0
    module = importlib.import_module(COMMANDS[pre.command][0])
    sub_action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    module.add_arguments(sub_action.choices[pre.command])
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(module.run(args))
    except DsteleopError as exc:
        print(f"dsteleop {pre.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dsteleop {pre.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
