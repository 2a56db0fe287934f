"""The one-slot broadcaster that hands the loop's tick records to other threads.

The loop publishes one immutable `TickRecord` per tick (`Broadcaster` is one of its
observers). Each subscriber (the browser view, the demo restarter, a bench, a test) owns a
one-slot mailbox: publishing overwrites it, so a slow or stalled subscriber only ever skips
records (coalesced, counted in `dropped`) and never slows the loop.
"""

from __future__ import annotations

import threading

from dsteleop.app.session.schema import TickRecord


class Subscription:
    """A one-slot mailbox for one observer."""

    def __init__(self, broadcaster: Broadcaster) -> None:
        self._broadcaster = broadcaster
        self._cond = threading.Condition()
        self._item: TickRecord | None = None
        self._fresh = False
        self.received = 0
        self.dropped = 0

    def _put(self, item: TickRecord) -> None:
        with self._cond:
            if self._fresh:
                self.dropped += 1  # the observer never saw the previous one
            self._item, self._fresh = item, True
            self.received += 1
            self._cond.notify_all()

    def latest(self) -> TickRecord | None:
        """The newest snapshot (seen or not), without waiting."""
        with self._cond:
            self._fresh = False
            return self._item

    def wait(self, timeout_s: float) -> TickRecord | None:
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

    def publish(self, item: TickRecord) -> None:
        for sub in self._subs:  # copy-on-write list: no lock held while delivering
            sub._put(item)

    def observe(self, record: TickRecord) -> None:
        """The loop's observer call: publish to every subscription."""
        self.publish(record)
