"""A terminal progress bar the commands, the study, the sweep and tuning share (shared machinery
lives in app/tasks, not in app/cli, so the study and the sweep import no command)."""

from __future__ import annotations

import time
from typing import IO


class Progress:
    """A one-line progress bar on a terminal stream (nothing when disabled).

    Args:
        total: units of work.
        stream: where to draw (stderr; logs and JSON results stay on their own streams).
        enabled: draw at all (commands enable it on a terminal).
        label: the command, shown first.
        unit: what is counted.
    """

    def __init__(
        self,
        total: int,
        stream: IO[str],
        enabled: bool,
        label: str,
        unit: str,
        width: int = 30,
    ) -> None:
        self.total, self.stream, self.enabled, self.width = max(total, 1), stream, enabled, width
        self.label, self.unit = label, unit
        self.done = 0
        self.t0 = time.monotonic()
        self._last = -1.0
        self.status = ""  # shown after the counts (e.g. the best value so far)

    def __enter__(self) -> Progress:
        self._draw(force=True)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self._draw(force=True)
            self.stream.write("\n")
            self.stream.flush()

    def advance(self, n: int = 1, status: str | None = None) -> None:
        self.done = min(self.total, self.done + int(n))
        if status is not None:
            self.status = status
        self._draw()

    def eta_s(self) -> float | None:
        """Seconds left at the average rate so far (None before the first unit is done)."""
        if self.done == 0:
            return None
        elapsed = time.monotonic() - self.t0
        return elapsed * (self.total - self.done) / self.done

    def _draw(self, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < 0.1 and self.done < self.total:
            return
        self._last = now
        frac = self.done / self.total
        fill = round(frac * self.width)
        bar = "#" * fill + "." * (self.width - fill)
        msg = (
            f"\r{self.label} [{bar}] {frac:4.0%} {self.done}/{self.total} {self.unit} "
            f"{now - self.t0:5.1f} s"
        )
        eta = self.eta_s()
        if eta is not None and self.done < self.total:
            msg += f", ETA {eta:4.0f} s"
        if self.status:
            msg += f"  {self.status}"
        msg += "\x1b[K"  # clear what a longer earlier line left
        self.stream.write(msg)
        self.stream.flush()
