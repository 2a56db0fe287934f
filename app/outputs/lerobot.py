"""`--record-lerobot DIR`: each recorded episode written into a LeRobot v3.0 dataset as it
ends (`lerobot.live.LiveDataset`, docs/datasets.md); with a camera, its frames from the
session's video. The sessions behind it are recorded under DIR/.dsteleop-sessions unless
`--record` says where."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dsteleop.app.lerobot import SESSIONS, check_out_dir
from dsteleop.app.outpaths import output_dir
from dsteleop.app.outputs import OutputBase, OutputContext, OutputKind

if TYPE_CHECKING:
    from dsteleop.app.lerobot.live import LiveDataset
    from dsteleop.app.session.episodes import Episode
    from dsteleop.app.session.schema import TickRecord
    from dsteleop.tracking.sources import SourceSpec


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--record-lerobot",
        type=output_dir,
        default=None,
        metavar="DIR",
        help="also write the recorded episodes as a LeRobot v3.0 dataset into the new or empty "
        "folder DIR, each as it ends (docs/datasets.md); implies --record-video for a camera "
        "or video source",
    )


def parse(args: argparse.Namespace, source: SourceSpec) -> Path | None:
    """The dataset's folder, new or empty (checked before a camera or the robot opens)."""
    if args.record_lerobot is None:
        return None
    check_out_dir(args.record_lerobot)
    return Path(args.record_lerobot)


class DatasetOutput(OutputBase):
    """Hands each recorded episode to the live dataset, which writes it on its own thread."""

    def __init__(self, dataset: LiveDataset) -> None:
        self.dataset = dataset

    def episode(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        self.dataset.put(folder, meta, episode, ticks)

    def summary(self) -> dict[str, Any]:
        return self.dataset.summary()

    def close(self) -> None:
        self.dataset.close()


def open_output(root: Path, ctx: OutputContext) -> DatasetOutput:
    from dsteleop.app.lerobot.live import LiveDataset

    return DatasetOutput(LiveDataset(root, round(ctx.rate_hz), camera=ctx.frames))


KIND = OutputKind(
    "lerobot",
    add_arguments,
    parse,
    open_output,
    wants_frames=True,
    sessions=lambda root: Path(root) / SESSIONS,
)
