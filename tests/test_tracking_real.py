"""Real MediaPipe (the Tasks HandLandmarker, the model shipped in the package) on the real
videos and photos of ../shared/data.

Each video is tracked once per session (module fixture, ~1000 frames in all). Frame ranges
below were annotated by looking at the videos (see the comments); they are ground truth about
the footage, not outputs of the tracker.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.tracking import (
    Detection,
    DetectorConfig,
    HandSample,
    HandTracker,
    ImageFolderSource,
    SelectionConfig,
    TrackerConfig,
    VideoFileSource,
    iter_samples,
)
from dsteleop.tracking.selection import palm_centre_image

pytestmark = pytest.mark.slow

VIDEOS = (
    "open_hand_wave_landscape",
    "webcam_fist_thumb",
    "webcam_two_hands",
    "portrait_fingers_open_close",
)
# Minimum detection rates. One hand in clear view all along: 0.95. The hand of
# webcam_fist_thumb leaves the frame for its last ~70 of 324 frames (so at most ~0.78 is
# possible); in webcam_two_hands the followed hand leaves the frame near the end and the
# other is taken only after the 0.5 s re-acquisition delay.
MIN_RATE = {
    "open_hand_wave_landscape": 0.95,
    "webcam_fist_thumb": 0.7,
    "webcam_two_hands": 0.8,
    "portrait_fingers_open_close": 0.9,
}


@pytest.fixture(scope="module")
def tracked(shared_data: Path) -> dict[str, list[HandSample]]:
    out = {}
    for name in VIDEOS:
        with HandTracker(TrackerConfig()) as tracker:
            src = VideoFileSource(shared_data / "videos" / f"{name}.mp4")
            out[name] = [s for _, s in iter_samples(src, tracker)]
    return out


@pytest.mark.parametrize("name", VIDEOS)
def test_detection_rate_per_video(tracked: dict[str, list[HandSample]], name: str) -> None:
    samples = tracked[name]
    rate = np.mean([s.detected for s in samples])
    assert len(samples) > 100
    assert rate >= MIN_RATE[name], f"{name}: detection rate {rate:.3f}"
    for s in samples:
        if s.detected:
            assert s.has_pose and 0.05 < s.p_cam_palm_m[2] < 3.0
            assert np.all((s.openness >= 0) & (s.openness <= 1))


def median_openness(samples: list[HandSample], lo: int, hi: int) -> NDArray[np.float64]:
    window = [s.openness for s in samples[lo:hi] if s.detected]
    assert len(window) >= (hi - lo) // 2, f"hand not seen in frames {lo}-{hi}"
    return np.median(window, axis=0)


def test_openness_falls_when_fingers_fold(tracked: dict[str, list[HandSample]]) -> None:
    """portrait_fingers_open_close: the back of a left hand over a desk. Annotated frames:
    15-25, 160-170 and 255-265 all fingers spread; 45-55 thumb tucked; 90-100 index and
    middle folded (thumb still tucked); 120-130 ring and little folded (thumb tucked);
    215-222 a fist."""
    s = tracked["portrait_fingers_open_close"]
    open_ = np.min([median_openness(s, a, a + 10) for a in (15, 160, 255)], axis=0)
    assert np.all(open_ > 0.6)
    thumb, index, middle, ring, little = range(5)
    folds = {
        (45, 55): [thumb],
        (90, 100): [thumb, index, middle],
        (120, 130): [thumb, ring, little],
        (215, 222): [index, middle, ring, little],
    }
    for (lo, hi), fingers in folds.items():
        g = median_openness(s, lo, hi)
        for f in fingers:
            assert g[f] < open_[f] - 0.2, f"frames {lo}-{hi}, finger {f}: {g[f]:.2f}"
        folded = [f for f in fingers if f != thumb]
        straight = [f for f in range(1, 5) if f not in fingers]
        if folded and straight:  # the fingers still up stay well above the folded ones
            assert min(g[straight]) > max(g[folded]) + 0.2, (lo, hi, g)


def test_fist_with_thumb_out(tracked: dict[str, list[HandSample]]) -> None:
    """webcam_fist_thumb: a fist with the thumb out for its first ~220 frames."""
    g = np.array([s.openness for s in tracked["webcam_fist_thumb"][:220] if s.detected])
    assert len(g) > 150
    assert np.median(g[:, 0]) > 0.6
    assert np.all(np.median(g[:, 1:], axis=0) < 0.2)


def test_two_hands_one_followed_consistently(tracked: dict[str, list[HandSample]]) -> None:
    """webcam_two_hands shows both hands: the tracker keeps to one, never jumping between
    them from frame to frame: one handedness label while followed, and no move between two
    detections closer than the re-acquisition delay larger than the selection gate."""
    cfg = SelectionConfig()
    samples = [s for s in tracked["webcam_two_hands"] if s.detected]
    prev = None
    segments = 1
    for s in samples:
        assert s.landmarks_image is not None
        c = palm_centre_image(_detection(s), s.width_px / s.height_px)
        if prev is not None:
            gap = s.t_capture_s - prev[0]
            if gap <= cfg.reacquire_after_s:
                assert np.linalg.norm(c - prev[1]) <= cfg.max_jump
                assert s.handedness == prev[2]
            else:
                segments += 1
        prev = (s.t_capture_s, c, s.handedness)
    assert segments <= 2  # at most one hand-over, after the followed hand left the view


def _detection(s: HandSample) -> Detection:
    assert s.landmarks_image is not None and s.handedness is not None
    return Detection(s.landmarks_image, s.landmarks_world, s.handedness, s.score)


def test_photos_detection_and_gesture_openness(shared_data: Path) -> None:
    """The 40 gesture photos (static mode: every image on its own). The README reports 36
    of 40 found by this model; per gesture the openness pattern must hold on all but at most
    one detected photo of that gesture."""
    config = TrackerConfig(detector=DetectorConfig(static_images=True), filter_reset_s=0.0)
    folder = ImageFolderSource(shared_data / "hand_images")
    found = 0
    fails: dict[str, list[str]] = {"four": [], "rock": [], "call": []}
    with HandTracker(config) as tracker:
        for frame, _ in iter_samples(folder, HandTracker(config, tracker.detector)):
            name = folder.files[frame.seq].name
            tracker.reset()  # photos are unrelated: no hand following across them
            s = tracker.process(frame)
            found += int(s.detected)
            if not s.detected:
                continue
            thumb, index, middle, ring, little = s.openness
            gesture = name.split("_")[0]
            ok = {
                "four": min(index, middle, ring, little) > thumb,
                "rock": min(index, little) > max(middle, ring),
                "call": thumb > max(index, middle, ring),
            }.get(gesture, True)
            if not ok:
                fails[gesture].append(name)
    assert found >= 34
    assert all(len(v) <= 1 for v in fails.values()), fails
