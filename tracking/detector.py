"""Hand landmark detector: MediaPipe Tasks `HandLandmarker` with the model shipped in dsteleop.

One code path for every source: the Tasks API (`mediapipe.tasks.python.vision`), present
with the same interface in mediapipe 0.10.21 and in the 1.x releases. The model is the
`hand_landmarker.task` file shipped as package data (`tracking/models`, sha256-checked at
load) or a `.task` file the user names; nothing is downloaded. MediaPipe is imported when a
detector is built, never at import time. The detector returns every hand it finds as
`Detection`s; choosing one hand is `selection.py`'s job.

Running modes: IMAGE for unrelated photos (palm detection on every image); VIDEO for
everything else, files and replay as well as the live camera thread. In VIDEO mode MediaPipe
follows a hand from its previous box and runs the palm detector only when the hand is lost;
`detect_for_video` returns on the calling thread, so the tracking thread hands its sample on
as soon as MediaPipe is done. (LIVE_STREAM would deliver the same result through a callback
on a MediaPipe thread: one more thread hop and a wait in the tracking thread for nothing,
since `TrackingStream` already keeps only the newest frame; docs/tracking.md.) VIDEO mode
needs strictly increasing timestamps in whole milliseconds: a frame stamped at or before the
previous one is given the previous stamp + 1 ms.

Handedness: MediaPipe labels hands as if the image were mirrored (a selfie view), so on an
unmirrored camera image its "Left" is the operator's right hand. The detector corrects the
label with `mirrored` and reports the anatomical hand.
"""

from __future__ import annotations

import importlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dsteleop.errors import ConfigError, InputError
from dsteleop.tracking.types import Detection, Handedness, Image, other_hand

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of the landmark detector.

    Attributes:
        task_model_path: a `hand_landmarker.task` file to load instead of the model shipped
            with dsteleop (None: the shipped one, sha256-checked; no file or network needed).
        max_num_hands: hands the detector looks for. 1 is fastest: MediaPipe then follows
            the hand from its previous box and runs the palm detector only when it is lost;
            2 runs the palm detector on every frame with fewer than 2 hands (about half the
            frame rate) but lets the selector choose among both hands of a two-hand view.
        min_detection_confidence: palm detector score threshold in [0, 1].
        min_presence_confidence: the landmark model's hand-presence score threshold in
            [0, 1]; below it the hand counts as lost and the palm detector runs again.
        min_tracking_confidence: overlap (IoU) threshold in [0, 1] between the hand's box
            in this frame and the previous one for the hand to count as followed.
        static_images: treat every frame as unrelated (photos): palm detection every frame.
        mirrored: images are flipped left-right (selfie view); fixes the handedness labels.
    """

    task_model_path: Path | None = None
    max_num_hands: int = 1
    min_detection_confidence: float = 0.5
    min_presence_confidence: float = 0.5
    min_tracking_confidence: float = 0.5
    static_images: bool = False
    mirrored: bool = False

    def __post_init__(self) -> None:
        if self.max_num_hands < 1:
            raise ConfigError(f"max_num_hands must be >= 1, got {self.max_num_hands!r}")
        for name in (
            "min_detection_confidence",
            "min_presence_confidence",
            "min_tracking_confidence",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"{name} must be in [0, 1], got {value!r}")


class HandDetector(Protocol):
    """Finds hands in BGR images. `t_s` is the frame time (VIDEO mode needs it)."""

    def detect(self, image_bgr: Image, t_s: float) -> list[Detection]: ...

    def close(self) -> None: ...


def _anatomical(label: str, mirrored: bool) -> Handedness:
    hand: Handedness = "Right" if label == "Right" else "Left"
    return hand if mirrored else other_hand(hand)


def _to_array(landmark_list: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.array([(p.x, p.y, p.z) for p in landmark_list], dtype=np.float64)


def _model_bytes(path: Path | None) -> tuple[bytes, str]:
    """The model to load and a name for it in messages (module docstring)."""
    if path is None:
        from dsteleop.tracking.models import MODEL_FILE, hand_model_bytes

        return hand_model_bytes(), f"{MODEL_FILE} (shipped with dsteleop)"
    if not path.is_file():
        raise InputError(f"hand landmarker model not found: {path}")
    try:
        return path.read_bytes(), str(path)
    except OSError as exc:
        raise InputError(f"cannot read hand landmarker model {path}: {exc.strerror}") from exc


class TaskHandDetector:
    """MediaPipe Tasks `HandLandmarker` (module docstring): VIDEO mode, or IMAGE mode for
    `static_images`."""

    def __init__(self, config: DetectorConfig) -> None:
        data, name = _model_bytes(config.task_model_path)
        cv2 = importlib.import_module("cv2")
        mp = importlib.import_module("mediapipe")
        vision = importlib.import_module("mediapipe.tasks.python.vision")
        BaseOptions = importlib.import_module("mediapipe.tasks.python").BaseOptions
        self._cv2 = cv2
        self._mp = mp
        self._config = config
        self._video = not config.static_images
        self._last_ms = -1
        options = vision.HandLandmarkerOptions(
            base_options=BaseOptions(model_asset_buffer=data),
            running_mode=vision.RunningMode.VIDEO if self._video else vision.RunningMode.IMAGE,
            num_hands=config.max_num_hands,
            min_hand_detection_confidence=config.min_detection_confidence,
            min_hand_presence_confidence=config.min_presence_confidence,
            min_tracking_confidence=config.min_tracking_confidence,
        )
        try:
            self._landmarker = vision.HandLandmarker.create_from_options(options)
        except (RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"cannot load hand landmarker model {name}: {first}") from exc
        log.info("hand landmarks: MediaPipe Tasks HandLandmarker, model %s", name)

    def detect(self, image_bgr: Image, t_s: float) -> list[Detection]:
        """All hands in the image; `t_s` [s] should increase between calls (module docstring)."""
        rgb = self._cv2.cvtColor(image_bgr, self._cv2.COLOR_BGR2RGB)
        image = self._mp.Image(image_format=self._mp.ImageFormat.SRGB, data=rgb)
        if self._video:
            t_ms = max(round(t_s * 1000.0), self._last_ms + 1)
            self._last_ms = t_ms
            result = self._landmarker.detect_for_video(image, t_ms)
        else:
            result = self._landmarker.detect(image)
        out = []
        for lm, world, cls in zip(
            result.hand_landmarks, result.hand_world_landmarks, result.handedness, strict=False
        ):
            top = cls[0]
            out.append(
                Detection(
                    landmarks_image=_to_array(lm),
                    landmarks_world=_to_array(world),
                    handedness=_anatomical(str(top.category_name), self._config.mirrored),
                    score=float(top.score),
                )
            )
        return out

    def close(self) -> None:
        self._landmarker.close()


def make_detector(config: DetectorConfig) -> HandDetector:
    """The detector for `config` (this is where MediaPipe and the model get loaded)."""
    return TaskHandDetector(config)
