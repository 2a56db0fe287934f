"""Operator controls: a small locked mailbox that UI callbacks write and the loop reads.

GUI callbacks (the browser view, tests, the CLI) never touch the loop's state directly: they
post requests here, and the loop takes all pending requests once per tick, at the start of
the tick, and applies them in its own thread. Requests of the same kind coalesce (the last
one wins), so a burst of slider events costs the loop one change. The one exception is the
operator's stop: a Stop and a Resume posted within the same tick leave the robot stopped (from
two tabs at once, the stop wins; a Resume pressed again a tick later resumes).
"""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Requests:
    """What the operator asked for since the last tick (None / False: nothing asked).

    Attributes:
        mode: switch arbitration mode ("DS", "S", "manual", "autonomous").
        calibrate: re-centre the hand mapping on the current hand pose.
        reset: restart the task (with `utensil` if given).
        utensil: the utensil to pick at the next reset.
        record: True to start recording, False to stop; None: no change.
        params: hyper-parameter changes by name (kappa, p, q, b, window, goal_noise_m, ...).
        stop: True to stop the robot (latched: it halts as for a lost hand and stays halted),
            False to resume; None: no change.
    """

    mode: str | None = None
    calibrate: bool = False
    reset: bool = False
    utensil: str | None = None
    record: bool | None = None
    params: dict[str, Any] = field(default_factory=dict)
    stop: bool | None = None

    @property
    def empty(self) -> bool:
        return self == Requests()


class Controls:
    """Thread-safe request mailbox (write from any thread, `take()` from the loop)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending = Requests()

    def _update(self, **changes: Any) -> None:
        with self._lock:
            cur = self._pending
            params = {**cur.params, **changes.pop("params", {})}
            self._pending = Requests(**{**cur.__dict__, **changes, "params": params})

    def set_mode(self, mode: str) -> None:
        self._update(mode=mode)

    def calibrate(self) -> None:
        self._update(calibrate=True)

    def reset(self, utensil: str | None = None) -> None:
        self._update(reset=True, utensil=utensil)

    def choose_utensil(self, utensil: str) -> None:
        self._update(utensil=utensil)

    def set_recording(self, on: bool) -> None:
        self._update(record=on)

    def set_params(self, **params: Any) -> None:
        self._update(params=params)

    def stop_robot(self) -> None:
        """Stop the robot (latched until `resume_robot`)."""
        self._update(stop=True)

    def resume_robot(self) -> None:
        """Let the hand drive the robot again after a stop (ignored if a stop is pending)."""
        with self._lock:
            if self._pending.stop is not True:  # a stop in the same tick wins
                self._pending = dataclasses.replace(self._pending, stop=False)

    def take(self) -> Requests:
        """All pending requests, clearing them (called by the loop once per tick)."""
        with self._lock:
            out, self._pending = self._pending, Requests()
            return out
