"""The `dsteleop` command: a thin dispatcher over one module per sub-command (app/cli/).

Each sub-command module has `add_arguments(parser)` and `run(args) -> int`, turns its
arguments into one typed, checked command object and imports what it runs only inside
`run`, so `dsteleop --help` and `dsteleop COMMAND --help` stay instant and never load
MediaPipe, PyBullet or Viser. Every path a command writes is checked before it runs
(`app/outpaths.py`: the options whose `type` is `output_file` or `output_dir`). A
`DsteleopError` anywhere becomes one line on stderr and its exit code (2; 3 for a lost
robot, `RobotLostError`; the only exceptions caught here); Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

from dsteleop import __version__
from dsteleop.app.outpaths import check_outputs
from dsteleop.errors import DsteleopError

# name -> (module, one-line help). Add a command by adding a line here.
COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("dsteleop.app.cli.bench", "run benchmarks and print one JSON object"),
    "export": ("dsteleop.app.cli.export", "export sessions as a LeRobot v3.0 dataset"),
    "run": ("dsteleop.app.cli.run", "run the loop without a browser (headless or live); record"),
    "replay": ("dsteleop.app.cli.replay", "replay recorded sessions or videos headless; metrics"),
    "sim": ("dsteleop.app.cli.sim", "reproduce the paper's simulation study (S vs DS); report"),
    "robot": (
        "dsteleop.app.cli.robot",
        "check a robot description: task placement, reach, steady state, grasp (robot check)",
    ),
    "robot-sim": (
        "dsteleop.app.cli.robot_sim",
        "run the PyBullet robot at the far end of a Zenoh link (ROS 2-compatible)",
    ),
    "serve": ("dsteleop.app.cli.serve", "run the live session and its browser view"),
    "track": ("dsteleop.app.cli.track", "track a hand in a video, images, camera or synthetic"),
    "tune": ("dsteleop.app.cli.tune", "tune the arbitration's hyper-parameters (Optuna, Ray)"),
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
    # The matrices here are tiny (3x3 to 7x7): a BLAS thread pool only competes with the
    # capture, tracking and control threads. Must be set before numpy loads.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # The command is the first argument that names one; its module adds its own options
    # before parsing, so `dsteleop COMMAND --help` lists them.
    command = next((a for a in argv if a in COMMANDS), None)
    if command is None:
        if not argv:
            parser.print_help()
            return 0
        parser.parse_args(argv)  # --help, --version, or a one-line error
        parser.print_help()
        return 0
    module = importlib.import_module(COMMANDS[command][0])
    sub_action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    sub_parser = sub_action.choices[command]
    module.add_arguments(sub_parser)
    args = parser.parse_args(argv)
    from dsteleop.app.cli.native_log import route_native_stderr

    # MediaPipe's, FFmpeg's and OpenCV's own stderr lines go to logging at debug level.
    with route_native_stderr():
        logging.basicConfig(
            level=logging.DEBUG if args.verbose else logging.INFO,
            format="%(asctime)s %(levelname)s %(name)s: %(message)s",
            stream=sys.stderr,
        )
        try:
            check_outputs(sub_parser, args)  # every path it writes, before anything opens
            return int(module.run(args))
        except DsteleopError as exc:
            print(f"dsteleop {command}: error: {exc}", file=sys.stderr)
            return exc.exit_code
        except KeyboardInterrupt:
            print(f"dsteleop {command}: interrupted", file=sys.stderr)
            return 130


if __name__ == "__main__":
    sys.exit(main())
