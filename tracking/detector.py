"""Hand landmark detectors: MediaPipe Hands (bundled models) or a MediaPipe Tasks model file.

MediaPipe is imported when a detector is built, never at import time. Both detectors return
every hand they find as `Detection`s; choosing one hand is `selection.py`'s job.

Handedness: MediaPipe labels hands as if the image were mirrored (a selfie view), so on an
unmirrored camera image its "Left" is the operator's right hand. The detectors correct the
label with `mirrored` and report the anatomical hand.
"""

from __future__ import annotations

import importlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from dsteleop.errors import InputError
from dsteleop.tracking.types import Detection, Handedness, Image, other_hand

log = logging.getLogger(__name__)

ModelComplexity = Literal["lite", "full"]
_COMPLEXITY = {"lite": 0, "full": 1}


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of the landmark detector.

    Attributes:
        model: bundled MediaPipe Hands landmark model: "lite" (faster) or "full".
        task_model_path: a `hand_landmarker.task` file for the MediaPipe Tasks API instead
            of the bundled models (None: bundled, no file or network needed).
        max_num_hands: hands the detector looks for. 1 is fastest: MediaPipe then follows
            the hand from its previous box and runs the palm detector only when it is lost;
            2 runs the palm detector on every frame with fewer than 2 hands (about half the
            frame rate) but lets the selector choose among both hands of a two-hand view.
        min_detection_confidence: palm detector threshold in [0, 1].
        min_tracking_confidence: landmark tracking threshold in [0, 1]; below it the palm
            detector runs again.
        static_images: treat every frame as unrelated (photos): palm detection every frame.
        mirrored: images are flipped left-right (selfie view); fixes the handedness labels.
    """

    model: ModelComplexity = "full"
    task_model_path: Path | None = None
    max_num_hands: int = 1
    min_detection_confidence: float = 0.5
    min_tracking_confidence: float = 0.5
    static_images: bool = False
    mirrored: bool = False

    def __post_init__(self) -> None:
        if self.model not in _COMPLEXITY:
            raise ValueError(f"model must be 'lite' or 'full', got {self.model!r}")
        if self.max_num_hands < 1:
            raise ValueError(f"max_num_hands must be >= 1, got {self.max_num_hands!r}")
        for name in ("min_detection_confidence", "min_tracking_confidence"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value!r}")


class HandDetector(Protocol):
    """Finds hands in BGR images. `t_s` is the frame time (the Tasks API needs it)."""

    def detect(self, image_bgr: Image, t_s: float) -> list[Detection]: ...

    def close(self) -> None: ...


def _anatomical(label: str, mirrored: bool) -> Handedness:
    hand: Handedness = "Right" if label == "Right" else "Left"
    return hand if mirrored else other_hand(hand)


def _to_array(landmark_list: Any) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.array([(p.x, p.y, p.z) for p in landmark_list], dtype=np.float64)


class MediaPipeHandsDetector:
    """`mp.solutions.hands` with the models bundled in the pinned mediapipe wheel."""

    def __init__(self, config: DetectorConfig) -> None:
        cv2 = importlib.import_module("cv2")
        mp = importlib.import_module("mediapipe")
        self._cv2 = cv2
        self._config = config
        self._hands = mp.solutions.hands.Hands(
            static_image_mode=config.static_images,
            max_num_hands=config.max_num_hands,
            model_complexity=_COMPLEXITY[config.model],
            min_detection_confidence=config.min_detection_confidence,
            min_tracking_confidence=config.min_tracking_confidence,
        )

    def detect(self, image_bgr: Image, t_s: float) -> list[Detection]:
        """All hands in the image (t_s is unused: the graph keeps its own clock)."""
        rgb = self._cv2.cvtColor(image_bgr, self._cv2.COLOR_BGR2RGB)
        rgb.flags.writeable = False
        result = self._hands.process(rgb)
        if not result.multi_hand_landmarks:
            return []
        worlds = result.multi_hand_world_landmarks or [None] * len(result.multi_hand_landmarks)
        out = []
        for lm, world, cls in zip(
            result.multi_hand_landmarks, worlds, result.multi_handedness, strict=False
        ):
            top = cls.classification[0]
            out.append(
                Detection(
                    landmarks_image=_to_array(lm.landmark),
                    landmarks_world=None if world is None else _to_array(world.landmark),
                    handedness=_anatomical(top.label, self._config.mirrored),
                    score=float(top.score),
                )
            )
        return out

    def close(self) -> None:
        self._hands.close()


class TaskHandDetector:
    """MediaPipe Tasks `HandLandmarker` from a user-supplied `hand_landmarker.task` file."""

    def __init__(self, config: DetectorConfig) -> None:
        cv2 = importlib.import_module("cv2")
        mp = importlib.import_module("mediapipe")
        vision = importlib.import_module("mediapipe.tasks.python.vision")
        BaseOptions = importlib.import_module("mediapipe.tasks.python").BaseOptions
        path = config.task_model_path
        if path is None or not path.is_file():
            raise InputError(f"hand landmarker model not found: {path}")
        self._cv2 = cv2
        self._mp = mp
        self._config = config
        self._video = not config.static_images
        self._last_ms = -1
        options = vision.HandLandmarkerOptions(
            base_options=BaseOptions(model_asset_path=str(path)),
            running_mode=vision.RunningMode.VIDEO if self._video else vision.RunningMode.IMAGE,
            num_hands=config.max_num_hands,
            min_hand_detection_confidence=config.min_detection_confidence,
            min_tracking_confidence=config.min_tracking_confidence,
        )
        try:
            self._landmarker = vision.HandLandmarker.create_from_options(options)
        except (RuntimeError, ValueError) as exc:
            raise InputError(f"cannot load hand landmarker model {path}: {exc}") from exc

    def detect(self, image_bgr: Image, t_s: float) -> list[Detection]:
        """All hands in the image; `t_s` must increase between calls in video mode."""
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
    """The detector the config asks for (this is where MediaPipe gets loaded)."""
    if config.task_model_path is not None:
        log.info("hand landmarks: MediaPipe Tasks model %s", config.task_model_path)
        return TaskHandDetector(config)
    log.info("hand landmarks: MediaPipe Hands, bundled %s model", config.model)
    return MediaPipeHandsDetector(config)
