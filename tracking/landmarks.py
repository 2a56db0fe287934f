"""MediaPipe's 21 hand landmarks, named once.

Every other module indexes landmarks through the names here, never through bare numbers.
Layout (MediaPipe Hands): 0 wrist; thumb 1-4 (CMC, MCP, IP, tip); then index, middle, ring
and little finger, four each (MCP, PIP, DIP, tip).
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

from dsteleop.errors import ContractError

N_LANDMARKS: Final = 21

WRIST: Final = 0
THUMB_CMC: Final = 1
THUMB_MCP: Final = 2
THUMB_IP: Final = 3
THUMB_TIP: Final = 4
INDEX_MCP: Final = 5
INDEX_PIP: Final = 6
INDEX_DIP: Final = 7
INDEX_TIP: Final = 8
MIDDLE_MCP: Final = 9
MIDDLE_PIP: Final = 10
MIDDLE_DIP: Final = 11
MIDDLE_TIP: Final = 12
RING_MCP: Final = 13
RING_PIP: Final = 14
RING_DIP: Final = 15
RING_TIP: Final = 16
LITTLE_MCP: Final = 17
LITTLE_PIP: Final = 18
LITTLE_DIP: Final = 19
LITTLE_TIP: Final = 20

#: Human fingers, thumb to little (docs/CONVENTIONS.md).
FINGER_NAMES: Final = ("thumb", "index", "middle", "ring", "little")

#: Per finger, the chain of landmarks from the wrist to the tip. The angles between
#: consecutive segments of a chain are the finger's joint flexions (see `pose.py`): for the
#: thumb at its MCP and IP joints, for the other fingers at MCP, PIP and DIP.
FINGER_CHAINS: Final[tuple[tuple[int, ...], ...]] = (
    (THUMB_CMC, THUMB_MCP, THUMB_IP, THUMB_TIP),
    (WRIST, INDEX_MCP, INDEX_PIP, INDEX_DIP, INDEX_TIP),
    (WRIST, MIDDLE_MCP, MIDDLE_PIP, MIDDLE_DIP, MIDDLE_TIP),
    (WRIST, RING_MCP, RING_PIP, RING_DIP, RING_TIP),
    (WRIST, LITTLE_MCP, LITTLE_PIP, LITTLE_DIP, LITTLE_TIP),
)

#: Landmarks whose mean is the palm centre (the origin of the palm frame).
PALM_CENTRE: Final = (WRIST, INDEX_MCP, MIDDLE_MCP, RING_MCP, LITTLE_MCP)

#: The rigid part of the hand, used to solve for the palm's depth: fingers articulate and
#: MediaPipe's finger-tip depths are its noisiest outputs.
PALM_RIGID: Final = (WRIST, THUMB_CMC, INDEX_MCP, MIDDLE_MCP, RING_MCP, LITTLE_MCP)

#: Skeleton edges, for drawing.
CONNECTIONS: Final[tuple[tuple[int, int], ...]] = (
    (WRIST, THUMB_CMC),
    (THUMB_CMC, THUMB_MCP),
    (THUMB_MCP, THUMB_IP),
    (THUMB_IP, THUMB_TIP),
    (WRIST, INDEX_MCP),
    (INDEX_MCP, INDEX_PIP),
    (INDEX_PIP, INDEX_DIP),
    (INDEX_DIP, INDEX_TIP),
    (INDEX_MCP, MIDDLE_MCP),
    (MIDDLE_MCP, MIDDLE_PIP),
    (MIDDLE_PIP, MIDDLE_DIP),
    (MIDDLE_DIP, MIDDLE_TIP),
    (MIDDLE_MCP, RING_MCP),
    (RING_MCP, RING_PIP),
    (RING_PIP, RING_DIP),
    (RING_DIP, RING_TIP),
    (RING_MCP, LITTLE_MCP),
    (WRIST, LITTLE_MCP),
    (LITTLE_MCP, LITTLE_PIP),
    (LITTLE_PIP, LITTLE_DIP),
    (LITTLE_DIP, LITTLE_TIP),
)


def check_landmarks(landmarks: NDArray[np.float64], name: str = "landmarks") -> None:
    """Raise ContractError unless `landmarks` is a (21, 3) array.

    Args:
        landmarks: array to check.
        name: how to call it in the message.
    """
    if landmarks.shape != (N_LANDMARKS, 3):
        raise ContractError(f"{name} must have shape (21, 3), got {landmarks.shape}")
