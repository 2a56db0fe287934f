"""Edges of a tuning campaign's best configuration: found, widened, reported.

A best value that lies at a range's end says the optimum may lie beyond it. After a campaign
(`dsteleop tune`'s trials over one search space):

    edge      a best value within `EDGE_FRACTION` (5 %) of its range's width of a range end,
              the width measured in log space for a log range (`log`, `intlog`); a choice
              has no edges
    widen     the range is widened on that side: a log range by a factor of `LOG_FACTOR`
              (4: LOW / 4 or HIGH x 4), a linear one by half its width (integer ranges
              rounded outwards); the new end is clipped to the field's domain
    domain    where a field's values end is not written here: it is probed, by asking the
              configuration to take a value (`ArbitrationConfig.replace`, the fields' and the
              modes' own validators, e.g. `check_range` in arbitration/modes/base.py), and a
              widened end that it rejects is moved back by bisection to the last value it
              takes (within 1e-4 of the range's width, log width for a log range). An edge
              whose end is already at the domain's bound (no value beyond it is taken) is
              reported as `domain`, not widened
    space     an integer log range cannot go below 1 (app/tune/space.py): an `intlog` low
              edge at 1 is reported as `space`, not widened

The command then runs a fresh campaign over the widened space with the same budget, until no
widenable edge remains or its rounds are done (app/cli/tune.py); every edge of the final best
is reported with what was done about it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

from dsteleop.app.tune.space import Dimension, Value, parse_dimension
from dsteleop.arbitration import ArbitrationConfig
from dsteleop.errors import ConfigError

#: A best value this close to an end, as a share of the range's width, is on that edge.
EDGE_FRACTION = 0.05
#: A log range's end moves by this factor when widened.
LOG_FACTOR = 4.0
#: A clipped end lies within this share of the range's width of the domain's bound.
CLIP_FRACTION = 1e-4

Side = Literal["low", "high"]
Status = Literal["widened", "domain", "space", "rounds", "off"]

#: What each status says, for summary.md and the log.
STATUS_TEXT: dict[str, str] = {
    "widened": "widened",
    "domain": "at its domain bound (the configuration takes no value beyond it): not widened",
    "space": "at 1, the least an integer log range allows: not widened",
    "rounds": "not widened: the widening rounds (--widen-edges) were used up",
    "off": "not widened: --widen-edges 0",
}


@dataclass(frozen=True)
class Edge:
    """One best value on an edge of its range.

    Attributes:
        name: the parameter.
        side: low or high end.
        value: the best value.
        end: the range's end it is close to.
        distance: |value - end| as a share of the range's width (log width for log ranges).
        status: widened, domain, space (module docstring), or rounds / off (widenable but
            not widened: no rounds left, or widening off).
        new_end: the widened end (widened only).
        clipped: the widened end was clipped to the field's domain.
    """

    name: str
    side: Side
    value: float
    end: float
    distance: float
    status: Status
    new_end: float | None = None
    clipped: bool = False

    @property
    def widenable(self) -> bool:
        return self.status in ("widened", "rounds", "off")

    def with_status(self, status: Status) -> Edge:
        return replace(self, status=status, new_end=None, clipped=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "side": self.side,
            "value": self.value,
            "end": self.end,
            "distance": self.distance,
            "status": self.status,
            "status_text": STATUS_TEXT[self.status],
            "new_end": self.new_end,
            "clipped": self.clipped,
        }

    def describe(self) -> str:
        s = f"{self.name} = {self.value:.4g} at the {self.side} end {self.end:.4g}: "
        if self.status == "widened":
            clip = " (clipped to the field's domain)" if self.clipped else ""
            return s + f"widened to {self.new_end:.6g}{clip}"
        return s + STATUS_TEXT[self.status]


def _t(d: Dimension, v: float) -> float:
    """A value in the coordinate edges are measured in (log for log ranges)."""
    return math.log(v) if d.log else v


def _inv(d: Dimension, t: float) -> float:
    return math.exp(t) if d.log else t


def edges_of(
    space: Sequence[Dimension], params: Mapping[str, Value]
) -> list[tuple[Dimension, Side]]:
    """The (dimension, side) of every best value on an edge (a dimension of width 0 or a
    choice has none)."""
    out: list[tuple[Dimension, Side]] = []
    for d in space:
        if d.kind == "choice" or d.name not in params:
            continue
        lo, hi, v = _t(d, d.low), _t(d, d.high), _t(d, float(params[d.name]))
        width = hi - lo
        if width <= 0:
            continue
        if (v - lo) / width <= EDGE_FRACTION:
            out.append((d, "low"))
        if (hi - v) / width <= EDGE_FRACTION:
            out.append((d, "high"))
    return out


def takes(base: ArbitrationConfig, d: Dimension, value: float) -> bool:
    """Whether the configuration takes `value` for `d` (its validators' answer)."""
    v: Value = int(value) if d.integer else float(value)
    try:
        base.replace(**{d.name: v})
    except ConfigError:
        return False
    return True


def _proposed(d: Dimension, side: Side) -> float:
    """The widened end before the domain is consulted (module docstring)."""
    if d.log:
        v = d.low / LOG_FACTOR if side == "low" else d.high * LOG_FACTOR
        if d.integer:
            v = max(1.0, math.floor(v)) if side == "low" else math.ceil(v)
        return v
    half = (d.high - d.low) / 2.0
    if d.integer:
        half = math.ceil(half)
    return d.low - half if side == "low" else d.high + half


def _clip(d: Dimension, base: ArbitrationConfig, end: float, target: float) -> float:
    """The farthest value from `end` (taken) towards `target` (not taken) that the
    configuration takes, found by bisection to within `CLIP_FRACTION` of the range's width
    and written as the shortest number there; `end` itself when nothing beyond it is
    taken."""
    if d.integer:
        i_ok, i_bad = int(end), int(target)
        while abs(i_bad - i_ok) > 1:
            i_mid = (i_ok + i_bad) // 2
            if takes(base, d, i_mid):
                i_ok = i_mid
            else:
                i_bad = i_mid
        return float(i_ok)
    step = CLIP_FRACTION * (_t(d, d.high) - _t(d, d.low))
    ok, bad = _t(d, end), _t(d, target)
    while abs(bad - ok) > step / 16:
        mid = (ok + bad) / 2.0
        if takes(base, d, _inv(d, mid)):
            ok = mid
        else:
            bad = mid
    if abs(ok - _t(d, end)) < step:
        return end
    # The shortest number (fewest significant digits, rounded to nearest or inwards) within
    # `step` of the bound that the configuration takes: an end a person can read.
    bound = _inv(d, ok)
    for digits in range(1, 16):
        for cand in (float(f"{bound:.{digits}g}"), _round_inwards(bound, digits, up=target < end)):
            if (cand > 0 or not d.log) and (
                abs(_t(d, cand) - ok) <= step
                and takes(base, d, cand)
                and (cand < end if target < end else cand > end)
            ):
                return cand
    return bound


def _short(v: float) -> float:
    return float(f"{v:.6g}")


def _round_inwards(v: float, digits: int, up: bool) -> float:
    """`v` to `digits` significant digits, rounded up (`up`) or down."""
    if v == 0:
        return 0.0
    scale = 10.0 ** (digits - 1 - math.floor(math.log10(abs(v))))
    r = (math.ceil(v * scale) if up else math.floor(v * scale)) / scale
    return float(f"{r:.{digits}g}")


def widen(
    space: Sequence[Dimension], params: Mapping[str, Value], base: ArbitrationConfig
) -> tuple[tuple[Dimension, ...], list[Edge]]:
    """The edges of `params` (a campaign's best) and the space with each widenable edge
    widened (module docstring). The space is unchanged when no edge is widened."""
    found = edges_of(space, params)
    edges: list[Edge] = []
    ends: dict[str, dict[Side, float]] = {}
    for d, side in found:
        end = d.low if side == "low" else d.high
        value = float(params[d.name])
        width = _t(d, d.high) - _t(d, d.low)
        distance = abs(_t(d, value) - _t(d, end)) / width
        if d.kind == "intlog" and side == "low" and d.low <= 1:
            edges.append(Edge(d.name, side, value, end, distance, "space"))
            continue
        target = _proposed(d, side)
        clipped = False
        if not takes(base, d, end):  # the end itself is outside the domain (out_of_domain)
            edges.append(Edge(d.name, side, value, end, distance, "domain"))
            continue
        if not takes(base, d, target):
            target, clipped = _clip(d, base, end, target), True
        elif takes(base, d, _short(target)):
            target = _short(target)  # 0.85, not 0.8500000000000001
        if target == end:
            edges.append(Edge(d.name, side, value, end, distance, "domain"))
            continue
        ends.setdefault(d.name, {})[side] = target
        edges.append(Edge(d.name, side, value, end, distance, "widened", target, clipped))
    out = []
    for d in space:
        if d.name in ends:
            lo = ends[d.name].get("low", d.low)
            hi = ends[d.name].get("high", d.high)
            out.append(parse_dimension(f"{d.name}={spec_of(d.kind, lo, hi)}"))
        else:
            out.append(d)
    return tuple(out), edges


def spec_of(kind: str, low: float, high: float) -> str:
    """A range's SPEC (app/tune/space.py) with these ends: `repr`-exact numbers, so the
    parsed range is the one meant."""

    def num(v: float) -> str:
        if kind in ("int", "intlog"):
            return str(int(v))
        s = f"{v:.6g}"
        return s if float(s) == v else repr(v)

    prefix = {"float": "", "log": "log:", "int": "int:", "intlog": "intlog:"}[kind]
    return f"{prefix}{num(low)}:{num(high)}"
