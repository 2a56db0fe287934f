"""Signals during a command: SIGINT and SIGTERM stop a loop at the end of its tick.

The handlers are installed for the duration of a `with` block only (the main thread's, where
signals are delivered) and the previous ones restored after, so that nothing outlives the
command: a process forked later (a pool's worker) must die of SIGTERM as usual.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType
from typing import Any, Protocol


class Stoppable(Protocol):
    def stop(self) -> None: ...


class StopOnSignal:
    """SIGINT/SIGTERM call `target.stop()` (main thread only); `received` names the signal.

    Args:
        target: what to stop (a loop).
        signals: the signals handled.
    """

    def __init__(
        self,
        target: Stoppable,
        signals: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM),
    ) -> None:
        self._target = target
        self._signals = signals
        self._old: dict[int, Any] = {}
        self.received: str | None = None

    def __enter__(self) -> StopOnSignal:
        if threading.current_thread() is threading.main_thread():
            for sig in self._signals:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        self.received = signal.Signals(signum).name
        self._target.stop()

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()
