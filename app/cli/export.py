"""`dsteleop export SESSION... --to lerobot --out DIR`: sessions as a LeRobot v3.0 dataset.

Every episode of the sessions (or of the folders of sessions) becomes an episode of a new
dataset at DIR (docs/datasets.md): one frame per control tick, the camera video re-encoded
with LeRobot's codec settings, the arbitration's per-dimension quantities and each
episode's outcome beside the standard columns. One JSON line on stdout; a progress bar on
stderr when it is a terminal (or with --progress).

    --task TEXT             the task string of every episode (default: from its utensil)
    --fps N                 the dataset's frame rate: the sessions' control rate (default)
    --episodes counted|all  only the episodes that ended with an outcome, or all (default)
    --codec av1|h264        the camera's codec: LeRobot's default AV1, or H.264 (faster)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dsteleop.app.outpaths import output_dir
from dsteleop.app.tasks.progress import Progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "inputs", nargs="+", metavar="SESSION", help="session folders or folders of sessions"
    )
    parser.add_argument(
        "--to", choices=("lerobot",), required=True, help="the format (LeRobot v3.0)"
    )
    parser.add_argument("--out", type=output_dir, required=True, help="the new dataset's folder")
    parser.add_argument("--task", default=None, help="the task string of every episode")
    parser.add_argument(
        "--fps", type=int, default=None, help="frames per second (the sessions' control rate)"
    )
    parser.add_argument(
        "--episodes",
        choices=("counted", "all"),
        default="all",
        help="export every episode (all) or those that ended with an outcome (counted)",
    )
    parser.add_argument(
        "--codec",
        choices=("h264", "av1"),
        default=None,
        help="the camera's codec: h264 (the default: several times faster to encode) or av1 "
        "(LeRobot's own default); LeRobot reads both",
    )
    parser.add_argument(
        "--progress", action="store_true", help="draw the progress bar even when not on a TTY"
    )


def run(args: argparse.Namespace) -> int:
    from dsteleop.app.lerobot.export import export, plan

    checked = plan([Path(p) for p in args.inputs], args.fps, args.episodes)
    show = bool(args.progress) or sys.stderr.isatty()
    with Progress(checked.ticks, sys.stderr, show, "export", "ticks") as bar:
        summary = export(
            [],
            Path(args.out),
            args.task,
            args.fps,
            args.episodes,
            advance=bar.advance,
            checked=checked,
            **({} if args.codec is None else {"codec": args.codec}),
        )
    json.dump(summary, sys.stdout)
    sys.stdout.write("\n")
    return 0
