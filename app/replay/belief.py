"""What a run's belief over its goal candidates did (a robot not told its goal, `--goal infer`):
counted from the records' `belief`, for `metrics.json`, the demo's table and the plots.

Over the pick phase (the candidates are the utensils; the place phase has one, the bin):

    grasped          the utensil the task's grasp event names (None: no grasp)
    map_final        the MAP candidate at the last tick of the pick phase
    map_right        map_final is the grasped utensil
    p_grasped_final  the belief's probability of the grasped utensil then
    map_switches     how often the MAP changed
    map_settled_s    when the MAP last changed, from the run's first tick [s] (0: never), when
                     it ended on the grasped utensil; None otherwise (`app.study.inference.
                     map_stats`, the study's own definition)
    confidence_mean  the mean confidence per dimension over the pick phase, and joint

Across runs (`aggregate_beliefs`): the share of runs whose MAP ended on the utensil grasped,
the median settle time over those, the mean switches and final probability.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from dsteleop.app.jsonable import finite
from dsteleop.app.session.schema import BeliefRecord, TickRecord
from dsteleop.robot.task import EventKind

#: The place phase's one candidate.
PLACE_NAMES = ("bin",)


def _num(x: float) -> float | None:
    """Finite, to four decimals (`finite`), or None."""
    v = finite(x)
    return None if v is None else round(v, 4)


def pick_beliefs(
    t_s: Sequence[float], beliefs: Sequence[BeliefRecord | None]
) -> list[tuple[float, BeliefRecord]]:
    """(time from the run's first tick [s], belief) of the pick phase's ticks."""
    if not len(t_s):
        return []
    t0 = float(t_s[0])
    return [
        (float(t) - t0, b)
        for t, b in zip(t_s, beliefs, strict=True)
        if b is not None and b.names != PLACE_NAMES
    ]


def grasped_utensil(records: Sequence[TickRecord]) -> str | None:
    """The utensil of the run's first grasp event, or None."""
    for r in records:
        for e in r.plant.events:
            if e.kind is EventKind.GRASP:
                return e.detail or None
    return None


def belief_metrics(
    t_s: Sequence[float],
    beliefs: Sequence[BeliefRecord | None],
    grasped: str | None,
    dims: Sequence[str],
    dt_s: float,
) -> dict[str, Any] | None:
    """A run's belief counts (module docstring) from its ticks' times and beliefs and the
    utensil it grasped; None for a run without a belief (told)."""
    from dsteleop.app.study.inference import map_stats

    picks = pick_beliefs(t_s, beliefs)
    if not picks:
        return None
    names = picks[-1][1].names
    maps = np.array([names.index(b.map_name) for _, b in picks], dtype=np.int64)
    final = picks[-1][1]
    target = names.index(grasped) if grasped in names else -1
    stats = map_stats(maps[:, None], np.array([len(maps)]), np.array([target], dtype=np.intp), dt_s)
    conf = np.stack([b.confidence for _, b in picks])
    return {
        "candidates": list(names),
        "grasped": grasped,
        "map_final": final.map_name,
        "map_right": grasped is not None and final.map_name == grasped,
        "p_grasped_final": None if grasped is None else _num(final.of(grasped)),
        "map_switches": int(stats.switches[0]),
        "map_settled_s": _num(float(stats.settled_s[0])),
        "confidence_mean": {d: _num(float(conf[:, i].mean())) for i, d in enumerate(dims)},
        "confidence_joint_mean": _num(float(np.mean([b.confidence_joint for _, b in picks]))),
        "pick_ticks": len(picks),
    }


def belief_metrics_of(records: Sequence[TickRecord], dt_s: float) -> dict[str, Any] | None:
    """`belief_metrics` of a run's records."""
    if not records:
        return None
    return belief_metrics(
        [r.t_s for r in records],
        [r.belief for r in records],
        grasped_utensil(records),
        records[0].dims,
        dt_s,
    )


def aggregate_beliefs(runs: Sequence[dict[str, Any] | None]) -> dict[str, Any] | None:
    """Over runs' `belief_metrics` (None entries: told runs, left out): how many runs, the
    share whose MAP ended on the utensil grasped (of those that grasped one), the median
    settle time over those, the mean switches, the mean final probability of the grasped."""
    got = [r for r in runs if r is not None]
    if not got:
        return None
    grasped = [r for r in got if r["grasped"] is not None]
    right = [r for r in grasped if r["map_right"]]
    settled = [r["map_settled_s"] for r in right if r["map_settled_s"] is not None]
    p = [r["p_grasped_final"] for r in grasped if r["p_grasped_final"] is not None]
    return {
        "runs": len(got),
        "grasped": len(grasped),
        "map_right": len(right),
        "map_right_share": _num(len(right) / len(grasped)) if grasped else None,
        "map_settled_s_median": _num(float(np.median(settled))) if settled else None,
        "map_switches_mean": _num(float(np.mean([r["map_switches"] for r in got]))),
        "p_grasped_final_mean": _num(float(np.mean(p))) if p else None,
    }
