"""The operator's hand as a session recorded it: the mapped input, tick by tick."""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import Any

from dsteleop.app.ports import HumanInput, InputArrivals
from dsteleop.app.session.schema import TickRecord
from dsteleop.arbitration import HandState


class RecordedHandInput:
    """Replays the mapped hand input recorded with each tick (headless replay).

    `poll(now)` returns the input recorded at the latest tick at or before `now`, so a replay
    run on the recorded tick times sees exactly what the live loop saw (already re-anchored:
    `reanchor` changes nothing).
    """

    def __init__(self, records: Sequence[TickRecord], description: str = "recording") -> None:
        self._inputs = [r.hand for r in records]
        self._times = [r.t_s for r in records]
        self._description = description
        self._last = self._times[-1] if self._times else 0.0
        self._now = -float("inf")

    def describe(self) -> str:
        return self._description

    def mapping_config(self) -> dict[str, Any]:
        return {}

    @property
    def finished(self) -> bool:
        return self._now >= self._last

    end_reason = "recording ended"

    @property
    def arrivals(self) -> InputArrivals | None:
        """None: a recording is replayed on the loop's own clock."""
        return None

    def start(self) -> None:
        pass

    def poll(self, now_s: float) -> HumanInput | None:
        self._now = now_s
        k = bisect.bisect_right(self._times, now_s + 1e-9) - 1
        return None if k < 0 else self._inputs[k]

    def reanchor(self, inp: HumanInput, X_target: HandState) -> HumanInput:
        return inp

    def calibrate(self) -> None:
        pass

    def close(self) -> None:
        pass
