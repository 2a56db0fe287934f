"""`--rerun FILE.rrd` and `--rerun-connect [ADDR]`: a Rerun recording of the run, written or
streamed while it runs (`rrd.live.RerunLogger`, its own thread; docs/recordings.md)."""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING, Any

from dsteleop.app.outpaths import output_file
from dsteleop.app.outputs import OutputBase, OutputContext, OutputKind
from dsteleop.app.rrd.target import DEFAULT_ADDR, RerunTarget

if TYPE_CHECKING:
    from dsteleop.app.rrd.live import RerunLogger
    from dsteleop.app.session.schema import TickRecord
    from dsteleop.tracking.sources import SourceSpec


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rerun",
        type=output_file,
        default=None,
        metavar="FILE.rrd",
        help="write a Rerun recording while running (open with: rerun FILE.rrd)",
    )
    parser.add_argument(
        "--rerun-connect",
        nargs="?",
        const=DEFAULT_ADDR,
        default=None,
        metavar="ADDR",
        help=f"stream to a Rerun viewer you started (default {DEFAULT_ADDR})",
    )


def parse(args: argparse.Namespace, source: SourceSpec) -> RerunTarget | None:
    if args.rerun is None and args.rerun_connect is None:
        return None
    return RerunTarget(args.rerun, args.rerun_connect)


class RerunOutput(OutputBase):
    """The Rerun logger as an output: it observes every tick (buffered for its thread)."""

    def __init__(self, logger: RerunLogger) -> None:
        self.logger = logger

    def observe(self, record: TickRecord) -> None:
        self.logger.observe(record)

    def summary(self) -> dict[str, Any]:
        return self.logger.summary()

    def close(self) -> None:
        self.logger.close()


def open_output(target: RerunTarget, ctx: OutputContext) -> RerunOutput:
    from dsteleop.app.rrd.live import RerunLogger

    name = ctx.record.name if ctx.record is not None else None
    return RerunOutput(
        RerunLogger(
            target,
            name or time.strftime("live-%Y%m%d-%H%M%S"),
            scene=ctx.task.scene(),
            plant_meta=ctx.task.describe(),
        )
    )


KIND = OutputKind("rerun", add_arguments, parse, open_output, wants_scene=True)
