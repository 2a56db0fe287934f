"""The hand landmark model shipped in the package (tracking/models): the file, its digest
check at load, and the one Tasks detector that loads it (real MediaPipe)."""

from __future__ import annotations

import hashlib
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from dsteleop.errors import DsteleopError, InputError, ModelFileError
from dsteleop.tracking import DetectorConfig, make_detector
from dsteleop.tracking.models import MODEL_FILE, hand_model_bytes

MODELS = Path(__file__).resolve().parents[1] / "tracking" / "models"
#: Size of MediaPipe's hand_landmarker.task (float16, version 1), as NOTICE states.
MODEL_BYTES = 7_819_105


def test_the_shipped_model_is_the_file_its_digest_and_notice_name() -> None:
    data = (MODELS / MODEL_FILE).read_bytes()
    assert len(data) == MODEL_BYTES
    digest, name = (MODELS / f"{MODEL_FILE}.sha256").read_text().split()
    assert name == MODEL_FILE and hashlib.sha256(data).hexdigest() == digest
    with zipfile.ZipFile(MODELS / MODEL_FILE) as z:
        assert sorted(z.namelist()) == ["hand_detector.tflite", "hand_landmarks_detector.tflite"]
    assert "Apache License" in (MODELS / "LICENSE").read_text()
    notice = (MODELS / "NOTICE").read_text()
    assert "7,819,105 bytes" in notice and "Apache" in notice
    assert hand_model_bytes() == data  # read through importlib.resources, digest checked


def _copy(tmp_path: Path) -> Path:
    folder = tmp_path / "models"
    folder.mkdir()
    for name in (MODEL_FILE, f"{MODEL_FILE}.sha256"):
        shutil.copy(MODELS / name, folder / name)
    return folder


def test_a_changed_byte_is_a_one_line_model_error(tmp_path: Path) -> None:
    folder = _copy(tmp_path)
    assert hand_model_bytes(folder) == (MODELS / MODEL_FILE).read_bytes()
    data = bytearray((folder / MODEL_FILE).read_bytes())
    data[len(data) // 2] ^= 0x01
    (folder / MODEL_FILE).write_bytes(bytes(data))
    with pytest.raises(ModelFileError, match="is damaged") as err:
        hand_model_bytes(folder)
    assert "\n" not in str(err.value) and "reinstall dsteleop" in str(err.value)
    (folder / MODEL_FILE).write_bytes(bytes(data[:1000]))  # a truncated copy
    with pytest.raises(ModelFileError, match="1000 bytes"):
        hand_model_bytes(folder)


def test_a_missing_model_or_digest_is_a_one_line_model_error(tmp_path: Path) -> None:
    folder = _copy(tmp_path)
    (folder / f"{MODEL_FILE}.sha256").write_text("\n")
    with pytest.raises(ModelFileError, match="holds no sha256"):
        hand_model_bytes(folder)
    (folder / f"{MODEL_FILE}.sha256").unlink()
    with pytest.raises(ModelFileError, match=r"hand_landmarker\.task\.sha256 is missing"):
        hand_model_bytes(folder)
    (folder / MODEL_FILE).unlink()
    with pytest.raises(ModelFileError, match=r"hand_landmarker\.task is missing"):
        hand_model_bytes(folder)
    assert issubclass(ModelFileError, InputError)  # the CLI's one line, exit code 2


def test_missing_task_model_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(DsteleopError, match="hand landmarker model not found"):
        make_detector(DetectorConfig(task_model_path=tmp_path / "hand_landmarker.task"))


@pytest.mark.slow
def test_a_user_model_that_is_not_a_model_is_a_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "hand_landmarker.task"
    bad.write_bytes(b"not a model bundle" * 100)
    with pytest.raises(InputError, match="cannot load hand landmarker model") as err:
        make_detector(DetectorConfig(task_model_path=bad))
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_video_mode_takes_repeated_and_backward_frame_times() -> None:
    """VIDEO mode needs increasing whole-millisecond stamps: a frame stamped at or before
    the previous one (a looped file, two frames within 1 ms) is still tracked."""
    detector = make_detector(DetectorConfig())
    try:
        blank = np.zeros((240, 320, 3), np.uint8)
        for t_s in (0.0, 0.0, 0.0004, 5.0, 1.0, 1.0):
            assert detector.detect(blank, t_s) == []
    finally:
        detector.close()


def test_track_with_a_damaged_shipped_model_is_one_line_and_exit_2(
    shared_data: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`dsteleop track` on a real video when the installed model file has been altered: the
    digest check (the real one, on a damaged copy) stops it before MediaPipe loads."""
    from dsteleop.app.cli.main import main
    from dsteleop.tracking import models

    folder = _copy(tmp_path)
    data = bytearray((folder / MODEL_FILE).read_bytes())
    data[-1] ^= 0xFF
    (folder / MODEL_FILE).write_bytes(bytes(data))
    check = models.hand_model_bytes
    monkeypatch.setattr(models, "hand_model_bytes", lambda folder_=None: check(folder))
    video = shared_data / "videos" / "webcam_two_hands.mp4"
    code = main(["track", str(video), "--out", str(tmp_path / "o.jsonl"), "--max-frames", "5"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "Traceback" not in "\n".join(err)
    assert err[-1].startswith("dsteleop track: error: the hand landmark model"), err[-1]
    assert "is damaged" in err[-1] and "reinstall dsteleop" in err[-1]


#: In a fresh interpreter: a tracker with a detector that finds nothing (no MediaPipe) warms
#: up, then tracks a synthetic hand; prints which compiled SO(3) functions the warm-up loaded
#: and whether the first sample after it starts its filters afresh (filtered == raw).
WARM_UP_PROBE = """
import numpy as np
from dsteleop.arbitration import se3
from dsteleop.tracking import Frame, HandTracker, synthesize_detection, palm_facing_camera
class NoHands:
    def detect(self, image, t_s):
        assert image.shape == (480, 640, 3)
        return []
    def close(self):
        pass
tracker = HandTracker(detector=NoHands())
before = [bool(f.signatures) for f in (se3._exp_batch, se3._log_relative_batch)]
tracker.warm_up(640, 480)
after = [bool(f.signatures) for f in (se3._exp_batch, se3._log_relative_batch)]
hand = synthesize_detection(np.array([0.1, 0.0, 0.6]), palm_facing_camera(), np.ones(5),
                            tracker.intrinsics(640, 480))
s = tracker.process(Frame(0, 10.0, 640, 480, detections=(hand,)))
fresh = bool(np.allclose(s.p_cam_palm_m, s.raw_p_cam_palm_m))
print(before, after, fresh)
"""


def test_warm_up_loads_the_filters_compiled_maths_and_leaves_no_state() -> None:
    """The orientation filter's compiled SO(3) functions load at their first call (0.5-2 s):
    `warm_up` makes that call, so it does not fall on the second frame with a hand."""
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-c", WARM_UP_PROBE], capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[-2] == "[False, False] [True, True] True", out.stdout
