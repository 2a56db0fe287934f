"""Follow one hand consistently when the detector finds several.

Rule (the operator's hand is the one being tracked; never jump between hands):
    1. keep only candidates of the requested hand (`hand`, anatomical) if one is set;
    2. while a hand is being followed (seen within `reacquire_after_s`), take the candidate
       whose palm centre in the image is nearest to where ours was last seen, and reject it
       (report no hand this frame) if it is farther than `max_jump` (a fraction of the image
       diagonal, however many frames were missed): that is another hand, not ours moving;
    3. otherwise (nothing followed yet, or lost for longer than `reacquire_after_s`) take the
       candidate nearest to where the hand was last seen, or the highest score if never seen.
The followed hand keeps the handedness label it was acquired with: MediaPipe's per-frame
label can flicker, and the palm frame's orientation depends on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from dsteleop.errors import ConfigError
from dsteleop.tracking.landmarks import PALM_CENTRE
from dsteleop.tracking.types import Array, Detection, Handedness

HandChoice = Literal["any", "Left", "Right"]
_PALM = np.asarray(PALM_CENTRE)


@dataclass(frozen=True)
class SelectionConfig:
    """Parameters of the hand selection (module docstring).

    Attributes:
        hand: "any", or the anatomical hand to follow ("Left" / "Right").
        max_jump: largest palm move from where it was last seen, as a fraction of the image
            diagonal (0.15: ~0.1 m at 0.5 m from a 60 deg camera, a 3 m/s hand between two
            frames at 30 fps; the operator's other hand, a shoulder-width away, is farther).
        reacquire_after_s: after this long without our hand [s], any hand may be taken.
    """

    hand: HandChoice = "any"
    max_jump: float = 0.15
    reacquire_after_s: float = 0.5

    def __post_init__(self) -> None:
        if self.hand not in ("any", "Left", "Right"):
            raise ConfigError(f"hand must be 'any', 'Left' or 'Right', got {self.hand!r}")
        if not (math.isfinite(self.max_jump) and self.max_jump > 0):
            raise ConfigError(f"max_jump must be finite and > 0, got {self.max_jump!r}")
        if not (math.isfinite(self.reacquire_after_s) and self.reacquire_after_s >= 0):
            raise ConfigError(f"reacquire_after_s must be >= 0, got {self.reacquire_after_s!r}")


def palm_centre_image(detection: Detection, aspect: float) -> Array:
    """Palm centre (2,) in units of the image diagonal; `aspect` = width / height."""
    c = detection.landmarks_image[_PALM, :2].mean(0)
    return c * np.array([aspect, 1.0]) / math.hypot(aspect, 1.0)


class HandSelector:
    """Stateful chooser of the followed hand among a frame's detections."""

    def __init__(self, config: SelectionConfig) -> None:
        self.config = config
        self._last_c: Array | None = None
        self._last_t = -math.inf
        self._hand: Handedness | None = None

    @property
    def handedness(self) -> Handedness | None:
        """Label of the followed hand (locked at acquisition), or None."""
        return self._hand

    def reset(self) -> None:
        """Forget the followed hand."""
        self._last_c = None
        self._last_t = -math.inf
        self._hand = None

    def select(
        self, detections: tuple[Detection, ...] | list[Detection], t_s: float, aspect: float
    ) -> Detection | None:
        """The followed hand in this frame, or None.

        Args:
            detections: every hand found in the frame.
            t_s: frame time [s].
            aspect: image width / height.
        """
        cfg = self.config
        cands = [d for d in detections if cfg.hand in ("any", d.handedness)]
        following = self._last_c is not None and t_s - self._last_t <= cfg.reacquire_after_s
        if not cands:
            return None
        centres = [palm_centre_image(d, aspect) for d in cands]
        if self._last_c is None:
            k = int(np.argmax([d.score for d in cands]))
        else:
            dist = [float(np.linalg.norm(c - self._last_c)) for c in centres]
            k = int(np.argmin(dist))
            if following and dist[k] > cfg.max_jump:
                return None
        if not following or self._hand is None:
            self._hand = cands[k].handedness
        self._last_c, self._last_t = centres[k], t_s
        chosen = cands[k]
        if chosen.handedness != self._hand:
            chosen = Detection(
                chosen.landmarks_image, chosen.landmarks_world, self._hand, chosen.score
            )
        return chosen
