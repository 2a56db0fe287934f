"""Hand sources, the per-frame tracker on synthetic landmarks, and the threaded stream."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.arbitration import HandState, so3_log
from dsteleop.errors import DsteleopError
from dsteleop.tracking import (
    Frame,
    HandSample,
    HandTracker,
    ImageFolderSource,
    LandmarkNoise,
    SyntheticSource,
    TrackerConfig,
    TrackingStream,
    VideoFileSource,
    WebcamSource,
    iter_frames,
    iter_samples,
    open_source,
    scripted_trajectory,
)
from dsteleop.tracking.sources import SourceSpec
from tests.deadlines import HUNG_S, wait_for


def write_video(path: Path, n: int, size: tuple[int, int] = (64, 48), fps: float = 25.0) -> None:
    """Frame k is a flat grey of level 20 k (mod 240): readable back after compression."""
    w = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), fps, size)
    for k in range(n):
        w.write(np.full((size[1], size[0], 3), 20 * k % 240, dtype=np.uint8))
    w.release()


def one_line_error(excinfo: pytest.ExceptionInfo[DsteleopError]) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    return message


def test_video_file_every_frame_on_its_own_clock(tmp_path: Path) -> None:
    path = tmp_path / "v.mp4"
    write_video(path, 12, fps=25.0)
    src = VideoFileSource(path, size=(32, 24))
    src.open()
    frames = []
    while (f := src.read()) is not None:
        frames.append(f)
    src.close()
    assert [f.seq for f in frames] == list(range(12))
    assert [f.t_capture_s for f in frames] == pytest.approx([k / 25.0 for k in range(12)])
    assert all(f.image is not None and f.image.shape == (24, 32, 3) for f in frames)


def test_video_file_in_real_time_skips_overdue_frames(tmp_path: Path) -> None:
    path = tmp_path / "v.mp4"
    write_video(path, 60, fps=100.0)
    src = VideoFileSource(path, realtime=True)
    src.open()
    first = src.read()
    time.sleep(0.1)  # a consumer 10 frame periods late
    second = src.read()
    src.close()
    assert first is not None and second is not None and second.image is not None
    assert src.skipped >= 8  # (a loaded machine may oversleep: no upper bound)
    # The frame delivered is the one due now, not the next one in the file.
    level = 20 * (1 + src.skipped) % 240
    assert int(second.image[0, 0, 0]) == pytest.approx(level, abs=8)


def test_video_file_in_real_time_is_paced(tmp_path: Path) -> None:
    path = tmp_path / "v.mp4"
    write_video(path, 6, fps=50.0)
    src = VideoFileSource(path, realtime=True)
    src.open()
    t0 = time.monotonic()
    n = 0
    while src.read() is not None:
        n += 1
    elapsed = time.monotonic() - t0
    src.close()
    assert n == 6
    assert elapsed >= 5 / 50.0 - 0.005  # the 6th frame is due 100 ms after the first


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (None, "not found"),
        (b"", "empty"),
        (b"\x00garbage not a video\xff" * 50, "cannot read video|no readable frames"),
    ],
)
def test_bad_video_files_raise_one_line(tmp_path: Path, content: bytes | None, match: str) -> None:
    path = tmp_path / "bad.mp4"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(DsteleopError, match=match) as excinfo:
        VideoFileSource(path).open()
    assert str(path) in one_line_error(excinfo)


def test_video_without_frames_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "zero.mp4"
    write_video(path, 0)
    with pytest.raises(DsteleopError) as excinfo:
        VideoFileSource(path).open()
    assert "zero.mp4" in one_line_error(excinfo)


def test_camera_that_does_not_open_lists_the_ones_that_do() -> None:
    with pytest.raises(DsteleopError, match="camera 97 does not open") as excinfo:
        WebcamSource(97).open()
    assert "cameras that open:" in one_line_error(excinfo)


def test_image_folder(tmp_path: Path) -> None:
    for name, value in (("b.png", 20), ("a.jpg", 10), ("c.png", 30)):
        cv2.imwrite(str(tmp_path / name), np.full((20, 30, 3), value, dtype=np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    src = ImageFolderSource(tmp_path, fps=10.0)
    src.open()
    frames = [src.read() for _ in range(4)]
    assert frames[3] is None
    got = [f for f in frames if f is not None]
    assert [int(f.image[0, 0, 0]) for f in got if f.image is not None] == pytest.approx(
        [10, 20, 30], abs=2
    )
    assert [f.t_capture_s for f in got] == pytest.approx([0.0, 0.1, 0.2])


def test_image_folder_errors(tmp_path: Path) -> None:
    with pytest.raises(DsteleopError, match="no images"):
        ImageFolderSource(tmp_path).open()
    with pytest.raises(DsteleopError, match="not found"):
        ImageFolderSource(tmp_path / "missing").open()
    (tmp_path / "broken.png").write_bytes(b"not a png")
    src = ImageFolderSource(tmp_path)
    src.open()
    with pytest.raises(DsteleopError, match=r"broken\.png"):
        src.read()


def test_open_source_dispatch(tmp_path: Path) -> None:
    assert isinstance(open_source("synthetic"), SyntheticSource)
    assert isinstance(open_source("0"), WebcamSource)
    assert isinstance(open_source("/dev/video3"), WebcamSource)
    assert isinstance(open_source(str(tmp_path)), ImageFolderSource)
    # The prefixed forms of the --source grammar, as text or parsed.
    cam = open_source("webcam:2")
    assert isinstance(cam, WebcamSource) and cam.device == 2
    dev = open_source(SourceSpec("webcam", "/dev/video1"))
    assert isinstance(dev, WebcamSource) and dev.device == "/dev/video1"
    imgs = open_source(f"images:{tmp_path}")
    assert isinstance(imgs, ImageFolderSource) and imgs.path == tmp_path
    write_video(tmp_path / "v.mp4", 2)
    for text in (f"video:{tmp_path / 'v.mp4'}", str(tmp_path / "v.mp4")):
        vid = open_source(text)
        assert isinstance(vid, VideoFileSource) and vid.path == tmp_path / "v.mp4"
    with pytest.raises(DsteleopError, match="not found") as excinfo:
        open_source(str(tmp_path / "nope.mp4"))
    assert "nope.mp4" in one_line_error(excinfo)
    # demo and auto are the app's sources (app.sources), not tracking's.
    for kind in ("demo", "auto"):
        with pytest.raises(DsteleopError, match="not a tracking source"):
            open_source(SourceSpec(kind))


def test_tracker_on_synthetic_landmarks_filters_towards_the_truth() -> None:
    """The demo path: synthetic landmarks go straight to the estimator (no pixels, no
    MediaPipe). With detector noise, the filtered pose is closer to the truth than the raw
    one over a smooth operator motion."""
    src = SyntheticSource(
        scripted_trajectory(),
        duration_s=8.0,
        noise=LandmarkNoise(image_px=1.5, world_m=0.003),
        seed=4,
    )
    src.keep_truth = True
    tracker = HandTracker(TrackerConfig())
    raw_p, filt_p, raw_r, filt_r, raw_g, filt_g = [], [], [], [], [], []
    for frame, s in iter_samples(src, tracker):
        truth = src.truth[frame.seq]
        assert truth is not None and s.detected and frame.image is None
        pose, g = truth
        if frame.seq < 15:  # let the filters settle
            continue
        raw_p.append(np.linalg.norm(s.raw_p_cam_palm_m - pose.position))
        filt_p.append(np.linalg.norm(s.p_cam_palm_m - pose.position))
        raw_r.append(np.linalg.norm(so3_log(s.raw_R_cam_palm @ pose.rotation.T)))
        filt_r.append(np.linalg.norm(so3_log(s.R_cam_palm @ pose.rotation.T)))
        raw_g.append(np.abs(s.raw_openness - g).mean())
        filt_g.append(np.abs(s.openness - g).mean())
    assert tracker._detector is None  # never loaded MediaPipe
    assert np.median(filt_p) < np.median(raw_p)
    assert np.median(filt_r) < np.median(raw_r)
    assert np.median(filt_g) < np.median(raw_g)


def test_lost_hand_holds_the_pose_and_reports_no_detection() -> None:
    base = scripted_trajectory()

    def hides(t: float) -> tuple[HandState, NDArray[np.float64]] | None:
        return None if 1.0 <= t < 2.0 else base(t)

    samples = [s for _, s in iter_samples(SyntheticSource(hides, duration_s=2.5), HandTracker())]
    lost = [s for s in samples if 1.0 <= s.t_capture_s < 2.0]
    assert lost and not any(s.detected for s in lost)
    assert all(np.array_equal(s.p_cam_palm_m, lost[0].p_cam_palm_m) for s in lost)
    assert all(s.landmarks_image is None and np.isnan(s.raw_openness).all() for s in lost)
    assert samples[-1].detected


class SlowTracker(HandTracker):
    """A tracker that takes `delay_s` per frame, like MediaPipe on a busy machine."""

    def __init__(self, delay_s: float) -> None:
        super().__init__()
        self.delay_s = delay_s

    def process(self, frame: Frame) -> HandSample:
        time.sleep(self.delay_s)
        return super().process(frame)


def test_stream_with_slow_tracker_drops_stale_frames_and_serves_the_newest() -> None:
    src = SyntheticSource(scripted_trajectory(), fps=200.0, duration_s=1.0, realtime=True)
    stream = TrackingStream(src, SlowTracker(0.02))
    assert stream.latest() is None
    t0 = time.monotonic()
    stream.start()
    try:
        first = stream.wait_for(0, timeout_s=5.0)
        assert first is not None
        # latest() takes no lock: it answers even while the stream's lock is held.
        held, release = threading.Event(), threading.Event()

        def hold() -> None:
            with stream._cond:
                held.set()
                release.wait(2.0)

        holder = threading.Thread(target=hold)
        holder.start()
        held.wait(2.0)
        assert stream.latest() is not None
        release.set()
        holder.join()
        while not stream.finished and time.monotonic() - t0 < 10.0:
            assert stream.latest() is not None
            time.sleep(0.01)
    finally:
        stream.stop()
    assert stream.error is None
    assert stream.captured == 201
    # About 1 frame in 4 can be tracked (5 ms frames, 20 ms tracking); the rest is dropped.
    assert stream.dropped > 100
    assert stream.tracked + stream.dropped == stream.captured
    last = stream.latest()
    assert last is not None and last.seq >= 195  # newest wins: the end of the run


def test_stream_over_a_file_like_source_tracks_every_frame() -> None:
    src = SyntheticSource(scripted_trajectory(), fps=30.0, duration_s=2.0)
    with TrackingStream(src, SlowTracker(0.002)) as stream:
        stream.wait_for(60, timeout_s=HUNG_S)
        wait_for(lambda: stream.finished)
    assert stream.dropped == 0 and stream.tracked == 61


def test_stream_reports_a_failing_source() -> None:
    class Failing(SyntheticSource):
        def read(self) -> Frame | None:
            if self._seq >= 3:
                raise DsteleopError("cannot read image (corrupt): x.png")
            return super().read()

    stream = TrackingStream(Failing(scripted_trajectory(), duration_s=5.0)).start()
    wait_for(lambda: stream.finished)
    stream.stop()
    assert isinstance(stream.error, DsteleopError)
    assert stream.tracked == 3


def test_importing_tracking_loads_neither_cv2_nor_mediapipe() -> None:
    code = (
        "import sys, dsteleop.tracking, dsteleop.app.cli.main, dsteleop.app.cli.track;"
        "print(sorted(m for m in ('cv2', 'mediapipe') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_prefetch_yields_the_same_frames_in_order_and_closes_early(tmp_path: Path) -> None:
    path = tmp_path / "v.mp4"
    write_video(path, 15)
    serial = [f.seq for f in iter_frames(VideoFileSource(path))]
    ahead = [f.seq for f in iter_frames(VideoFileSource(path), prefetch=2)]
    assert serial == ahead == list(range(15))
    src = VideoFileSource(path)
    frames = iter_frames(src, prefetch=2)
    assert next(frames).seq == 0
    frames.close()  # abandoning the iteration stops the reader and closes the source
    assert src._cap is None


def test_prefetch_reraises_a_reader_error_in_the_consumer(tmp_path: Path) -> None:
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"{k}.png"), np.zeros((8, 8, 3), dtype=np.uint8))
    (tmp_path / "3.png").write_bytes(b"broken")
    seen = []
    with pytest.raises(DsteleopError, match=r"3\.png"):
        for f in iter_frames(ImageFolderSource(tmp_path), prefetch=2):
            seen.append(f.seq)
    assert seen == [0, 1, 2]
