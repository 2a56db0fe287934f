"""A video as the live source (`serve`/`run --realtime --source video:PATH`).

The clip plays from its first frame when the loop starts (the model is loaded before), the
loop says "video ended" when it has played, `--loop-video` plays it again, and `run
--realtime` stops at its end like a headless run.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

from dsteleop.app.cli.main import main
from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.session.schema import Status, TickRecord
from dsteleop.tracking.pipeline import TrackingStream
from dsteleop.tracking.sources import VideoFileSource
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


def _live_stream(
    clip: Path, seconds: float, loop_video: bool = False, idle_s: float = 0.0
) -> tuple[list[TickRecord], TrackingStream, int]:
    """Every tick record of a live loop on the clip, its tracking stream (its counts), and
    the frames the stream had captured after `idle_s` between the build and the first tick."""
    seen = Seen()
    extra: dict[str, Any] = {"loop_video": True} if loop_video else {}
    options = LoopOptions.of(f"video:{clip}", **extra)
    built = build(options, realtime=True, observers=(seen,))
    stream = getattr(built.loop.hand, "stream", None)
    assert isinstance(stream, TrackingStream)
    try:
        time.sleep(idle_s)
        before = stream.captured
        built.loop.run(max_ticks=round(seconds * built.loop.config.rate_hz))
    finally:
        built.loop.close()
    return seen.records, stream, before


def _live(clip: Path, seconds: float, loop_video: bool = False) -> list[TickRecord]:
    return _live_stream(clip, seconds, loop_video)[0]


def test_a_live_clip_plays_from_its_first_frame_and_says_when_it_ended(clip: Path) -> None:
    """The clip plays from its first frame, at the loop's first tick, to its last; the loop
    sees what the tracker tracked; the status says when the clip ended.

    Why this holds on a busy 2-core machine (before, it asked for 27 distinct frames of the
    45 and saw 23 at load ~5): how many frames MediaPipe keeps up with is the machine's speed,
    not the loop's behaviour. The paced file skips frames already a period overdue, the
    stream's one slot keeps the newest frame and counts each one it overwrites as dropped,
    and the tracker's speed itself is a figure of `dsteleop bench --only tracking`, never a
    test's. So the counts are read from the source and the stream, and each check is what the
    code promises given them, whatever the load:

    - nothing plays before the loop does: a few frame periods after `build` (the model
      loaded) nothing is captured (before the fix capture began at `build`, and a second or
      more of the clip was gone by the first tick);
    - the whole clip plays: each frame is delivered or skipped as overdue, `captured +
      skipped == CLIP_FRAMES`, and each delivered one tracked or dropped, `captured ==
      tracked + dropped`;
    - the last frame is tracked (no newer one overwrites it), so the loop sees the clip to its
      end: the last seen is frame `captured - 1`, and frames are seen in order;
    - the tick follows the camera (a tick starts on each new sample, docs/ARCHITECTURE.md), so
      the loop misses a tracked sample only when its own thread woke later than the next
      sample: it sees all of them but a quarter (at least one may be missed). A slow tracker
      spaces its samples further apart, which gives the loop more time, not less: measured
      under load 7-13 on 2 cores (others' work, and 0-3 busy processes beside the test), it
      saw at worst 3 of 4, 6 of 7, 12 of 14, 23 of 25 (tracked 2-25 of 45); unloaded 44-45.

    The first frame the loop sees has no bound of its own (it was frame 0 or 1 unloaded, 9 or
    13 at load 13, when the loop's thread woke after the tracker had published again): what
    the first tick promises is that the clip starts then, checked above by the counts.
    """
    period_s = 1.0 / 30.0
    records, stream, before = _live_stream(clip, 3.0, idle_s=5 * period_s)
    assert before == 0 and stream.started, f"{before} frames captured before the first tick"
    video = stream.source
    assert isinstance(video, VideoFileSource)
    seqs = [r.hand.seq for r in records if r.hand is not None]
    counts = (
        f"captured {stream.captured}, skipped {video.skipped}, tracked {stream.tracked}, "
        f"dropped {stream.dropped}"
    )
    assert stream.captured + video.skipped == CLIP_FRAMES, counts
    assert stream.captured == stream.tracked + stream.dropped, counts
    assert seqs and max(seqs) == stream.captured - 1 and seqs == sorted(seqs), (seqs, counts)
    seen = len(set(seqs))
    missable = max(1, stream.tracked // 4)
    assert seen >= stream.tracked - missable, (f"the loop saw {seen}", counts)
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
