"""Episodes: one attempt at the task each, from a task reset to its outcome (or to the next
reset, or to the end of the recording).

A session holds any number of episodes. Where one starts and ends is read from the tick
records alone, so a live recorder and a reader of a crashed or older session split a session
the same way:

    starts   a tick that carries `X_reset` (the first tick of a recording, and the tick after
             every task reset); a session without any (schema 1) starts one at its first tick
    ends     "outcome"    the tick the task decided its outcome (success, or a failure such as
                          `timeout`); the ticks after it, until the next reset, belong to none
             "reset"      a reset before any outcome: the attempt was abandoned
             "stopped"    the recording stopped before an outcome
             "incomplete" the session ends there without being closed (a killed process)

Only episodes that ended with an outcome are trials: they count in success rates and the
statistics (`counted`); the others are kept and listed, never counted as failures.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from dsteleop.app.session.schema import TickRecord, decode_outcome, encode_event, encode_outcome
from dsteleop.errors import FormatError
from dsteleop.robot.task import Outcome

End = Literal["outcome", "reset", "stopped", "incomplete"]
ENDS: tuple[End, ...] = ("outcome", "reset", "stopped", "incomplete")


@dataclass(frozen=True)
class Episode:
    """One attempt at the task (module docstring).

    Attributes:
        index: its number in the session, from 0.
        first, last: line numbers (from 0) of its first and last tick in `ticks.jsonl`.
        t_start_s, t_end_s: loop time of its first and last tick [s].
        end: how it ended (`ENDS`).
        outcome: the task's outcome when `end == "outcome"`, else None.
        mode: the arbitration mode at its start.
        utensil: the utensil of the attempt ("" when unknown).
        events: (tick k, event) of the task and the operator within it ("grasp:spoon", ...).
    """

    index: int
    first: int
    last: int
    t_start_s: float
    t_end_s: float
    end: End
    outcome: Outcome | None
    mode: str
    utensil: str = ""
    events: tuple[tuple[int, str], ...] = ()

    @property
    def n_ticks(self) -> int:
        return self.last - self.first + 1

    @property
    def counted(self) -> bool:
        """A trial: it ended with an outcome (module docstring)."""
        return self.end == "outcome" and self.outcome is not None

    @property
    def duration_s(self) -> float:
        """The outcome's time, or the span of its ticks [s]."""
        if self.outcome is not None and math.isfinite(self.outcome.time_s):
            return float(self.outcome.time_s)
        return self.t_end_s - self.t_start_s

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "first_tick": self.first,
            "last_tick": self.last,
            "t_start": self.t_start_s,
            "t_end": self.t_end_s,
            "duration_s": self.duration_s,
            "end": self.end,
            "outcome": encode_outcome(self.outcome),
            "mode": self.mode,
            "utensil": self.utensil,
            "events": [[k, e] for k, e in self.events],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Episode:
        """An episode of a session's metadata.

        Raises:
            KeyError, FormatError, TypeError: a malformed entry (the reader names the file).
        """
        end = str(d["end"])
        if end not in ENDS:
            raise FormatError(f"unknown episode end {end!r}")
        return cls(
            index=int(d["index"]),
            first=int(d["first_tick"]),
            last=int(d["last_tick"]),
            t_start_s=float(d["t_start"]),
            t_end_s=float(d["t_end"]),
            end=end,
            outcome=decode_outcome(d.get("outcome")),
            mode=str(d.get("mode", "")),
            utensil=str(d.get("utensil", "")),
            events=tuple((int(k), str(e)) for k, e in d.get("events", ())),
        )


class EpisodeSplitter:
    """Splits tick records into episodes as they come (module docstring).

    `push` each record in order with its line number; it returns the episode that the record
    ended, if any; `finish` ends the open one at the end of the records.
    """

    def __init__(self) -> None:
        self._open: dict[str, Any] | None = None
        self._last: tuple[int, float] | None = None
        self._count = 0
        self._seen = False

    @property
    def count(self) -> int:
        """Episodes ended so far."""
        return self._count

    @property
    def current(self) -> int | None:
        """The index of the open episode, or None between episodes."""
        return None if self._open is None else self._count

    def push(self, line: int, record: TickRecord, utensil: str = "") -> Episode | None:
        """Take the record of `line`; returns the episode that it ended, if any."""
        ended: Episode | None = None
        starts = record.X_reset is not None or not self._seen
        self._seen = True
        if starts and self._open is not None:
            ended = self._close("reset")
        if starts:
            self._open = {
                "first": line,
                "t_start": record.t_s,
                "mode": record.mode.value,
                "utensil": utensil,
                "events": [],
            }
        self._last = (line, record.t_s)
        if self._open is None:
            return ended
        events = [*record.notes, *(encode_event(e) for e in record.plant.events)]
        self._open["events"].extend((record.k, e) for e in events)
        if record.outcome is not None:
            if not self._open["utensil"]:
                self._open["utensil"] = record.outcome.utensil
            return self._close("outcome", record.outcome)
        return ended

    def finish(self, end: End = "stopped") -> Episode | None:
        """End the open episode (if any) at the last record pushed."""
        return None if self._open is None else self._close(end)

    def _close(self, end: End, outcome: Outcome | None = None) -> Episode:
        assert self._open is not None and self._last is not None
        o = self._open
        last, t_end = self._last
        episode = Episode(
            index=self._count,
            first=int(o["first"]),
            last=last,
            t_start_s=float(o["t_start"]),
            t_end_s=t_end,
            end=end,
            outcome=outcome,
            mode=str(o["mode"]),
            utensil=str(o["utensil"]),
            events=tuple(o["events"]),
        )
        self._count += 1
        self._open = None
        return episode


def split(records: Iterable[TickRecord], end: End = "incomplete") -> list[Episode]:
    """The episodes of a session's records; an episode still open at the end ends `end`."""
    splitter = EpisodeSplitter()
    out = [e for i, r in enumerate(records) if (e := splitter.push(i, r)) is not None]
    last = splitter.finish(end)
    return out if last is None else [*out, last]


def episode_records(records: Sequence[TickRecord], episode: Episode) -> Sequence[TickRecord]:
    """The tick records of one episode."""
    return records[episode.first : episode.last + 1]
