"""Per-tick snapshots and the one-slot broadcaster that hands them to observers.

The loop publishes one immutable `Snapshot` per tick. Each subscriber (the browser view,
the recorder, tests) owns a one-slot mailbox: publishing overwrites it, so a slow or stalled
observer only ever skips snapshots (coalesced, counted in `dropped`) and never slows the loop.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import HandState

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Snapshot:
    """Everything observers may show about one tick (arrays are per dimension, 6 + F).

    Attributes:
        tick: tick index since the loop started.
        t_s: loop time of the tick [s] (monotonic, or the replay's clock).
        mode: arbitration mode name.
        status: "tracking", "lost" (input stale, robot halting or halted), or "assist".
        reason: why the input is not tracking ("no hand", "camera stalled", "invalid hand
            data", ...), "" while tracking.
        dims: dimension names (x, y, z, roll, pitch, yaw, fingers).
        alpha, P_human, P_robot, B, psi_human, psi_robot, U_human, U_robot, U_out: eq (1)-(8).
        X_human, X_current, X_goal: hand, robot and goal states in the base frame.
        phase: task phase name; outcome: "", "success" or "failure".
        events: task events of this tick.
        timing: loop timing (tick_ms, jitter_ms, rate_hz, overruns, latencies [ms]).
        hand: the human input of this tick (`app.hand_input.HumanInput`), or None.
        scene: link poses for the viewer (from the robot), or None.
        X_next: the pose commanded to the robot this tick.
        U_cmd: the velocity actually commanded (U_out while tracking; the halt ramp or the
            assist action otherwise).
        arbitrated: False when the input was stale and the arbitration did not run (the
            arrays then hold the last tick's values, for display).
    """

    tick: int
    t_s: float
    mode: str
    status: str
    reason: str
    dims: tuple[str, ...]
    alpha: Array
    P_human: Array
    P_robot: Array
    B: Array
    psi_human: Array
    psi_robot: Array
    U_human: Array
    U_robot: Array
    U_out: Array
    X_human: HandState | None
    X_current: HandState
    X_goal: HandState
    phase: str
    outcome: str
    events: tuple[str, ...] = ()
    timing: dict[str, float] = field(default_factory=dict)
    hand: Any = None
    scene: Any = None
    X_next: HandState | None = None
    U_cmd: Array | None = None
    arbitrated: bool = True


class Subscription:
    """A one-slot mailbox for one observer."""

    def __init__(self, broadcaster: Broadcaster) -> None:
        self._broadcaster = broadcaster
        self._cond = threading.Condition()
        self._item: Snapshot | None = None
        self._fresh = False
        self.received = 0
        self.dropped = 0

    def _put(self, item: Snapshot) -> None:
        with self._cond:
            if self._fresh:
                self.dropped += 1  # the observer never saw the previous one
            self._item, self._fresh = item, True
            self.received += 1
            self._cond.notify_all()

    def latest(self) -> Snapshot | None:
        """The newest snapshot (seen or not), without waiting."""
        with self._cond:
            self._fresh = False
            return self._item

    def wait(self, timeout_s: float) -> Snapshot | None:
        """The next snapshot not yet taken, or None after `timeout_s`."""
        with self._cond:
            if not self._fresh and not self._cond.wait_for(lambda: self._fresh, timeout_s):
                return None
            self._fresh = False
            return self._item

    def close(self) -> None:
        self._broadcaster.unsubscribe(self)


class Broadcaster:
    """Publishes snapshots to any number of one-slot subscriptions."""

    def __init__(self) -> None:
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()

    def subscribe(self) -> Subscription:
        sub = Subscription(self)
        with self._lock:
            self._subs = [*self._subs, sub]
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            self._subs = [s for s in self._subs if s is not sub]

    def publish(self, item: Snapshot) -> None:
        for sub in self._subs:  # copy-on-write list: no lock held while delivering
            sub._put(item)
