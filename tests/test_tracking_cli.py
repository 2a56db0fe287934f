"""`dsteleop track`: JSON Lines records, the summary on stdout, the preview, and errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from dsteleop.app.cli.main import main

RECORD_KEYS = {
    "t",
    "detected",
    "handedness",
    "score",
    "landmarks",
    "position",
    "rotvec",
    "openness",
}
SUMMARY_KEYS = {"frames", "detected", "detection_rate", "fps", "jitter"}


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_track_a_real_video_with_preview(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, preview = tmp_path / "track.jsonl", tmp_path / "preview.mp4"
    video = shared_data / "videos" / "open_hand_wave_landscape.mp4"
    argv = ["track", str(video), "--out", str(out), "--preview", str(preview)]
    assert main([*argv, "--max-frames", "40", "--size", "640x480"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert SUMMARY_KEYS <= set(summary)
    assert summary["frames"] == 40 and summary["detected"] == 40
    assert summary["detection_rate"] == 1.0 and summary["fps"] > 0
    assert 0.0 <= summary["jitter"] < 0.05
    records = read_jsonl(out)
    assert len(records) == 40
    for rec in records:
        assert RECORD_KEYS <= set(rec)
        assert rec["detected"] is True
        assert np.array(rec["landmarks"]).shape == (21, 3)
        assert len(rec["position"]) == 3 and len(rec["rotvec"]) == 3
        assert len(rec["openness"]) == 5
    # Frames of a file read as fast as possible carry the file's clock: seq / fps (~30 fps).
    steps = np.diff([r["t"] for r in records])
    assert np.allclose(steps, steps[0], atol=1e-5) and 1 / 35 < steps[0] < 1 / 25
    cap = cv2.VideoCapture(str(preview))
    n = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        assert img.shape == (480, 640, 3)
        n += 1
    assert n == 40


def test_track_synthetic_source(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "synthetic.jsonl"
    assert main(["track", "synthetic", "--out", str(out), "--duration", "2"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 61 and summary["detection_rate"] == 1.0
    positions = np.array([r["position"] for r in read_jsonl(out)])
    # The scripted operator stays within 10 cm of (0, 0, 0.5) m; noise adds millimetres.
    assert np.all(np.abs(positions - [0.0, 0.0, 0.5]) < 0.12)


def test_track_prefixed_sources(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The --source grammar's prefixed forms reach the same sources as the bare ones.
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"{k}.png"), np.full((48, 64, 3), 40 * k, dtype=np.uint8))
    out = tmp_path / "images.jsonl"
    assert main(["track", f"images:{frames}", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 3 and summary["detected"] == 0  # grey: no hand
    assert summary["source"].startswith(f"images in {frames}")
    assert [r["detected"] for r in read_jsonl(out)] == [False] * 3


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["track", "/no/such/video.mp4", "--out", "{tmp}/o.jsonl"], "video not found"),
        (["track", "video:/no/such/clip", "--out", "{tmp}/o.jsonl"], "video not found"),
        (["track", "images:/no/such/dir", "--out", "{tmp}/o.jsonl"], "image folder not found"),
        (["track", "demo", "--out", "{tmp}/o.jsonl"], "not demo"),
        (["track", "auto", "--out", "{tmp}/o.jsonl"], "not auto"),
        (["track", "nosuchkind:x", "--out", "{tmp}/o.jsonl"], "unknown source kind"),
        (["track", "synthetic", "--out", "/no/such/dir/o.jsonl"], "--out: no such folder"),
        (["track", "{tmp}/empty.mp4", "--out", "{tmp}/o.jsonl"], "empty"),
        (["track", "synthetic", "--out", "{tmp}/o.jsonl", "--size", "big"], "--size"),
        (["track", "97", "--out", "{tmp}/o.jsonl"], "camera 97 does not open"),
        (["track", "webcam:97", "--out", "{tmp}/o.jsonl"], "camera 97 does not open"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], match: str
) -> None:
    (tmp_path / "empty.mp4").write_bytes(b"")
    code = main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert match in err[-1] and err[-1].startswith("dsteleop track: error:")
    assert "Traceback" not in "\n".join(err)
