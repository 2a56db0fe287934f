"""A video as the live source (`serve`/`run --realtime --source video:PATH`).

The clip plays from its first frame when the loop starts (the model is loaded before), the
loop says "video ended" when it has played, `--loop-video` plays it again, and `run
--realtime` stops at its end like a headless run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from dsteleop.app.cli.compose import build
from dsteleop.app.cli.main import main
from dsteleop.app.cli.options import LoopOptions
from dsteleop.app.session.schema import Status, TickRecord
from tests.videos import read_frames, write_mp4

CLIP_FRAMES = 45  # 1.5 s at 30 fps


@pytest.fixture(scope="module")
def clip(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    video = shared_data / "videos" / "portrait_fingers_open_close.mp4"
    if not video.is_file():
        pytest.skip(f"test video not found: {video}")
    frames = [f[::2, ::2] for f in read_frames(video, CLIP_FRAMES)]
    return write_mp4(tmp_path_factory.mktemp("clip") / "clip.mp4", frames)


class Seen:
    """Observer: every tick record of a live loop."""

    def __init__(self) -> None:
        self.records: list[TickRecord] = []

    def observe(self, record: TickRecord) -> None:
        self.records.append(record)


def _live(clip: Path, seconds: float, loop_video: bool = False) -> list[TickRecord]:
    seen = Seen()
    extra: dict[str, Any] = {"loop_video": True} if loop_video else {}
    options = LoopOptions.of(f"video:{clip}", **extra)
    built = build(options, realtime=True, observers=(seen,))
    try:
        built.loop.run(max_ticks=round(seconds * built.loop.config.rate_hz))
    finally:
        built.loop.close()
    return seen.records


def test_a_live_clip_plays_from_its_first_frame_and_says_when_it_ended(clip: Path) -> None:
    records = _live(clip, 3.0)
    seqs = [r.hand.seq for r in records if r.hand is not None]
    # The loop sees the clip from its start (before: a second or more of it was gone while
    # the model loaded), and most of its frames (realtime: a slow tick may skip one).
    assert seqs and seqs[0] <= 3, seqs[:5]
    assert len(set(seqs)) >= 0.6 * CLIP_FRAMES
    # After the clip, the robot halts and the status says why: not a stalled camera. (Until
    # the source has ended a tick may read "camera stalled": on a busy 2-core machine a frame
    # can reach the loop more than stale_limit_s late, and halting then is the loop's job.)
    last = records[-1]
    assert last.status is Status.LOST and last.reason == "video ended", last.reason
    end = next(i for i, r in enumerate(records) if r.reason == "video ended")
    after = [r.reason for r in records[end:]]
    assert "camera stalled" not in after, after


def test_loop_video_plays_the_clip_again(clip: Path) -> None:
    records = _live(clip, 3.5, loop_video=True)
    seqs = [r.hand.seq for r in records if r.hand is not None]
    assert max(seqs) >= CLIP_FRAMES + 15  # well into the second pass
    assert not any(r.reason == "video ended" for r in records)


def test_run_realtime_stops_at_the_end_of_a_video(
    clip: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["run", "--source", f"video:{clip}", "--realtime", "--max-seconds", "30"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["stopped_by"] == "video ended"
    # The clip (1.5 s) and the half-second tail, not the 30 s limit.
    assert summary["ticks"] <= 30 * 4, summary["ticks"]
