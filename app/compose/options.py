"""What a loop is built from: the user's choices, parsed and checked (by the command line,
`app/cli/options.py`, or by code: benches, tests), as one typed value handed to `build`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dsteleop.app.loop import LoopConfig
from dsteleop.app.rrd.target import RerunTarget
from dsteleop.tracking.sources import SourceSpec, parse_source

#: A live session (`serve`) resets the task this long after each outcome, for the next
#: trial [s] (`--reset-after`).
RESET_AFTER_S = 4.0


@dataclass(frozen=True)
class LoopOptions:
    """The loop options of `run` and `serve`, checked (module docstring).

    Attributes:
        source: the hand source.
        loop: the loop configuration (mode, rate, lost policy, arbitration, ...).
        utensil: the utensil to pick.
        robot: the robot (`--robot`): a shipped description's name or a description file.
        seed: seed of the goal noise and the demo operator.
        goal_noise_m: goal position noise [m] (None: the task's default).
        record: the session folder (run) or root (serve), or None.
        record_video: record the camera frames too.
        record_lerobot: write the recorded episodes into a LeRobot dataset there, or None.
        loop_video: play a video source again when it ends.
        rotate: turn video or camera frames [deg clockwise] (None: a video's own rotation).
        allow_partial: accept a video that ends before the frames it declares.
        time_limit_s: a trial without an outcome after this long fails [s] (None: the
            task's default, 120 s).
        rerun: where a Rerun recording of the run goes, or None (docs/recordings.md).
        history: the operator history file (`--history`), or None: an empty history, kept
            nowhere.
        input_delay_given: the input delay was chosen (`--input-delay`, or a `--config`
            file's loop section), 0 included; otherwise the demo takes its world's delay.
    """

    source: SourceSpec
    loop: LoopConfig
    utensil: str = "spoon"
    robot: str = "iiwa"
    seed: int = 0
    goal_noise_m: float | None = None
    record: Path | None = None
    record_video: bool = False
    record_lerobot: Path | None = None
    loop_video: bool = False
    rotate: int | None = None
    allow_partial: bool = False
    time_limit_s: float | None = None
    rerun: RerunTarget | None = None
    history: Path | None = None
    input_delay_given: bool = False

    @classmethod
    def of(cls, source: str = "demo", loop: LoopConfig | None = None, **kw: Any) -> LoopOptions:
        """Options for code (benches, tests): a source in the `--source` grammar."""
        return cls(parse_source(source), loop or LoopConfig(), **kw)
