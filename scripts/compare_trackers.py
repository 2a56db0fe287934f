"""Side by side: the previous tracker (mp.solutions.hands) against the Tasks HandLandmarker.

Runs the whole tracker (`HandTracker.process`: landmarks, hand selection, palm pose, filters)
of two or more "sides", each a source tree run by the Python of an environment of its own
(each imports its own `mediapipe`, so they cannot share one process), on the same decoded
frames of each test video. The first side is the reference; typically:

    legacy   the tree at commit 17aadc1 (the last on mp.solutions.hands with its bundled full
             model) in an environment with mediapipe 0.10.21 (this checkout's .venv);
    tasks    this checkout ('.': the Tasks HandLandmarker, the model shipped in the package)
             in an environment with mediapipe 1.2.3 and numpy 2;
    tasks021 this checkout in the mediapipe 0.10.21 environment.

Every side is one process per video and round. It decodes the whole video first with its
tree's `VideoFileSource` (upright, as the app reads it) and loads the model (`warm_up`, not
timed); a digest of every decoded frame shows that all sides track the same pixels (the script
stops if not: use the same OpenCV build everywhere). Then the sides go in lockstep: frame i on
every side, one process at a time, the order rotating every frame, so that all see the same
load on the machine. Only `HandTracker.process` is timed.

Figures per video and side, against the reference: detection rate; median and p95 distance
between the image landmarks (x, y normalised by the image width and height: every landmark of
every frame where both found the hand); frames only one of them found the hand in; median ms
per frame over all rounds, its ratio to the reference's, and the median per-frame ratio.

    .venv/bin/python scripts/compare_trackers.py --rounds 3 --json /tmp/compare.json \
        --side legacy=.venv/bin/python@17aadc1 --side tasks=/tmp/mp123/bin/python@. \
        --side tasks021=.venv/bin/python@.

Needs git (for a commit's tree) and the test-data folder (--data, docs/test-data.md).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
VIDEOS = (
    "open_hand_wave_landscape",
    "webcam_fist_thumb",
    "webcam_two_hands",
    "portrait_fingers_open_close",
)


def worker(tree: Path, video: Path) -> None:
    """Track `video` with the `dsteleop` of `tree`, one frame per line read from stdin.

    Replies on stdout with one JSON line: first the frame count, environment and a digest of
    every decoded frame (after decoding them all into memory and loading the model), then
    per frame asked for its `HandTracker.process` time [ms], whether it found the hand and the
    image landmarks. Native libraries' output goes to stderr.
    """
    reply = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)  # anything else written to stdout (MediaPipe's C++) lands on stderr
    sys.path.insert(0, str(tree))
    import mediapipe

    import dsteleop
    from dsteleop.tracking import HandTracker, VideoFileSource
    from dsteleop.tracking.pipeline import iter_frames

    assert Path(dsteleop.__file__).resolve().is_relative_to(tree.resolve()), dsteleop.__file__
    frames = list(iter_frames(VideoFileSource(video)))
    digest = hashlib.sha256()
    for f in frames:
        assert f.image is not None
        digest.update(f.image.tobytes())
    tracker = HandTracker()
    tracker.warm_up(frames[0].width_px, frames[0].height_px)  # load the model, not timed
    head = {
        "frames": len(frames),
        "frames_sha256": digest.hexdigest(),
        "mediapipe": mediapipe.__version__,
        "numpy": np.__version__,
        "python": sys.version.split()[0],
    }
    reply.write(json.dumps(head) + "\n")
    reply.flush()
    for frame in frames:
        if not sys.stdin.readline():
            break
        t0 = time.perf_counter()
        sample = tracker.process(frame)
        ms = 1e3 * (time.perf_counter() - t0)
        lm = sample.landmarks_image
        row = {"ms": ms, "detected": sample.detected, "lm": None if lm is None else lm.tolist()}
        reply.write(json.dumps(row) + "\n")
        reply.flush()
    tracker.close()


def _legacy_tree(commit: str, into: Path) -> Path:
    archive = subprocess.run(
        ["git", "-C", str(REPO), "archive", "--format=tar", commit],
        check=True,
        capture_output=True,
    ).stdout
    tar = into / "legacy.tar"
    tar.write_bytes(archive)
    tree = into / f"legacy-{commit}"
    with tarfile.open(tar) as t:
        t.extractall(tree)
    return tree


class Side:
    """One tracker in its own process (`worker`), stepped one frame at a time."""

    def __init__(self, python: str, tree: Path, video: Path, log: Path) -> None:
        self._log = log.open("a")
        self.proc = subprocess.Popen(
            [python, __file__, "worker", "--tree", str(tree), "--video", str(video)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            text=True,
            env={**os.environ, "PYTHONPATH": ""},
        )
        self.head = self._read()
        self.ms: list[float] = []
        self.detected: list[bool] = []
        self.landmarks: list[Any] = []

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            sys.exit(f"worker failed: see {self._log.name}")
        row: dict[str, Any] = json.loads(line)
        return row

    def step(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("\n")
        self.proc.stdin.flush()
        row = self._read()
        self.ms.append(row["ms"])
        self.detected.append(row["detected"])
        self.landmarks.append(np.full((21, 3), np.nan) if row["lm"] is None else row["lm"])

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=60)
        self._log.close()


def _figures(ref: Side, other: Side, ms_ref: list[float], ms_other: list[float]) -> dict[str, Any]:
    a_det, b_det = np.array(ref.detected), np.array(other.detected)
    a_lm, b_lm = np.array(ref.landmarks, float), np.array(other.landmarks, float)
    both = a_det & b_det
    d = np.linalg.norm(a_lm[both, :, :2] - b_lm[both, :, :2], axis=-1)
    ms_a, ms_b = float(np.median(ms_ref)), float(np.median(ms_other))
    return {
        "same_frames": ref.head["frames_sha256"] == other.head["frames_sha256"],
        "detection_rate": round(float(np.mean(b_det)), 4),
        "only_reference": int(np.sum(a_det & ~b_det)),
        "only_this": int(np.sum(b_det & ~a_det)),
        "landmark_diff_median": round(float(np.median(d)), 5) if d.size else None,
        "landmark_diff_p95": round(float(np.percentile(d, 95)), 5) if d.size else None,
        "ms_median": round(ms_b, 2),
        "ms_ratio_to_reference": round(ms_b / ms_a, 3),
        "ms_ratio_per_frame_median": round(float(np.median(np.divide(ms_other, ms_ref))), 3),
    }


def _parse_side(text: str) -> tuple[str, str, str]:
    label, rest = text.split("=", 1)
    python, tree = rest.rsplit("@", 1)
    return label, python, tree


def compare(args: argparse.Namespace) -> dict[str, Any]:
    videos = args.data / "videos"
    sides = [_parse_side(text) for text in args.side]
    out: dict[str, Any] = {"rounds": args.rounds, "sides": {}, "videos": {}}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        trees: dict[str, Path] = {}
        for _, _, ref in sides:
            if ref not in trees:
                trees[ref] = REPO if ref == "." else _legacy_tree(ref, tmp)
        t0 = time.time()
        out["load_before"] = [round(x, 2) for x in os.getloadavg()]
        ms: dict[str, dict[str, list[float]]] = {}
        for name in VIDEOS:
            ms[name] = {label: [] for label, _, _ in sides}
            for k in range(args.rounds):
                procs = {
                    label: Side(py, trees[ref], videos / f"{name}.mp4", args.log)
                    for label, py, ref in sides
                }
                n = procs[sides[0][0]].head["frames"]
                for i in range(n):  # lockstep: each frame on every side, order rotating
                    labels = [label for label, _, _ in sides]
                    shift = i % len(labels)
                    for label in labels[shift:] + labels[:shift]:
                        procs[label].step()
                for label, proc in procs.items():
                    proc.close()
                    ms[name][label].extend(proc.ms)
                    out["sides"][label] = {
                        **{k2: proc.head[k2] for k2 in ("mediapipe", "numpy", "python")},
                        "tree": sides[[s[0] for s in sides].index(label)][2],
                    }
                if k == 0:
                    first = procs
                else:  # MediaPipe on the CPU is deterministic: every round finds the same
                    for label, proc in procs.items():
                        assert proc.detected == first[label].detected, (name, label)
            ref_label = sides[0][0]
            ref = first[ref_label]
            fig: dict[str, Any] = {
                "frames": ref.head["frames"],
                ref_label: {
                    "detection_rate": round(float(np.mean(ref.detected)), 4),
                    "ms_median": round(float(np.median(ms[name][ref_label])), 2),
                },
            }
            for label, _, _ in sides[1:]:
                fig[label] = _figures(ref, first[label], ms[name][ref_label], ms[name][label])
            out["videos"][name] = fig
            sys.stderr.write(f"{name}: {json.dumps(fig)}\n")
        out["load_after"] = [round(x, 2) for x in os.getloadavg()]
        out["wall_s"] = round(time.time() - t0, 1)
    for fig in out["videos"].values():
        for label, _, _ in sides[1:]:
            if not fig[label]["same_frames"]:
                sys.exit("the sides decoded different frames: use the same OpenCV build")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    sub = parser.add_subparsers(dest="cmd")
    w = sub.add_parser("worker")
    w.add_argument("--tree", type=Path, required=True)
    w.add_argument("--video", type=Path, required=True)
    parser.add_argument(
        "--side",
        action="append",
        default=[],
        metavar="LABEL=PYTHON@TREE",
        help="a tracker to run: its label, the Python of its environment and the source tree "
        "(a commit, or '.' for this checkout); the first is the reference (two or more)",
    )
    parser.add_argument("--log", type=Path, default=Path("/tmp/compare_trackers.log"))
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if args.cmd == "worker":
        worker(args.tree, args.video)
        return
    if len(args.side) < 2 or not all(re.fullmatch(r"[\w.-]+=[^@]+@[\w.-]+", s) for s in args.side):
        parser.error("give two or more --side LABEL=PYTHON@TREE")
    result = compare(args)
    text = json.dumps(result, indent=1)
    if args.json:
        args.json.write_text(text + "\n")
    sys.stdout.write(text + "\n")


if __name__ == "__main__":
    main()
