"""Headless replay of recorded sessions (and videos), and the paper's metrics over runs.

A session replays its recorded human input through a fresh loop, as fast as the machine
allows, once per requested mode: the same hand input at the same tick times, a fresh robot
and task with the session's seed and goal noise (`robot="simulated"`: the robot the session
recorded, the iiwa for sessions from before robots were descriptions; or a robot description
named or given as a file, `--robot NAME|FILE`), so the modes are paired; or against the
robot the session recorded (`robot="recorded"`, open loop: the recorded arbitration comes
back exactly, on any machine). `as_recorded` reads a session's
own ticks as it happened.

Metrics per run: those of the metric table (app/study/metric_table.py, each with its `replay`
definition; a metric registered there is one more), the paper's Section IV-D, over the ticks
where the arbitration ran; actions are compared in units of each dimension's velocity limit
(U / v_max), so metres, radians and openness weigh alike:

    cosine distance  the paper's: the SUM over actions of 1 - U_h.U_out / (|U_h| |U_out|);
                     beside it, labelled, the mean per action
                     (`cosine_distance_per_action_mean`)
    agreement        share of actions with U_h.U_out > 0
    success, time    the task's outcome and its duration [s]; `censored` when the episode
                     ended without an outcome or by the task's timeout (the time is a bound)
    mean_alpha       per dimension
    belief           a robot not told its goal (`--goal infer`): what its belief over the
                     candidates did (`app.replay.belief`: the MAP at the grasp against the
                     utensil grasped, when the MAP settled, its switches, the confidence)

Both action metrics skip the same idle actions (`metrics.idle_actions`: the operator's or the
output's action at most 1e-9 of the velocity limits), counted in `skipped_idle`.

A session holds episodes (one attempt at the task each, `session.episodes`); each replays on
its own, from its own reset. Across episodes, as the paper's Table I: success rate (Laplace,
adjusted-Wald CI), geometric means of time, cosine distance and agreement (CI of the log
mean; arithmetic means beside them, labelled), the censored times counted; and the paper's
tests between modes (N-1 chi-squared and McNemar's paired test on success, t-tests on log
time and on the per-episode cosine distance and agreement), over the episodes that ended
with an outcome, each test with its n and flagged as not meaningful under `MIN_EPISODES` a
mode. `divergences` gives Fig. 8's Jensen-Shannon divergences of the hand's and the robot's
(x, y, z) positions per mode.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.inputs.recorded import RecordedHandInput
from dsteleop.app.jsonable import finite, jsonable
from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.loop.timing import ManualClock
from dsteleop.app.ports import HandInput, Robot, Task
from dsteleop.app.replay.belief import aggregate_beliefs, belief_metrics
from dsteleop.app.session.episodes import Episode
from dsteleop.app.session.reader import Session
from dsteleop.app.session.schema import TickRecord
from dsteleop.app.session.trace import Trace
from dsteleop.app.study import metric_table
from dsteleop.arbitration import Mode, OperatorHistory, metrics
from dsteleop.errors import InputError
from dsteleop.robot.scene import SceneGeometry

Array = NDArray[np.float64]
#: "simulated" (the session's robot), "recorded", or a robot description's name or file.
RobotChoice = Literal["simulated", "recorded"] | str


def session_config(session: Session, mode: Mode | None) -> LoopConfig:
    """The loop config the session recorded, in `mode` when given."""
    cfg = LoopConfig.from_dict(session.meta.get("loop", {}))
    return cfg if mode is None else cfg.replace(mode=mode)


#: Receives a finished run's records and the plant's scene description (e.g. a Rerun writer).
RunSink = Callable[[Sequence[TickRecord], SceneGeometry | None], None]
#: The sink of a run, by the run's name (a session's episode, or a video) and mode.
SinkFor = Callable[[str, Mode], RunSink]


def run_headless(
    name: str,
    hand: HandInput,
    tick_times: Sequence[float],
    cfg: LoopConfig,
    world: tuple[Robot, Task],
    history: OperatorHistory | None = None,
    sink: RunSink | None = None,
) -> Trace:
    """Run a fresh loop over `tick_times` on a manual clock, as fast as possible, with the
    (robot, task) of `world`; its trace. `sink` gets the run's records before they close."""
    robot, task = world
    clock = ManualClock(tick_times[0] if tick_times else 0.0)
    loop = TeleopLoop(cfg, hand, robot, task, clock=clock, history=history or OperatorHistory())
    records: list[TickRecord] = []
    try:
        for t in tick_times:
            clock.sleep_until(t)
            records.append(loop.tick(t))
        if sink is not None:
            sink(records, task.scene())
    finally:
        loop.close()
    v_max = cfg.arbitration.v_max(len(robot.finger_names))
    return Trace.of(name, cfg.mode, records, v_max)


def simulated_world(
    meta: dict[str, Any], export_scene: bool = False, robot: str = "simulated"
) -> tuple[Robot, Task]:
    """A fresh simulated robot and kitchen task built from a session's metadata (its task's
    seed, noise and period; its robot, or the iiwa for a session recorded before robots were
    descriptions; `robot` a description's name or file instead of "simulated");
    `export_scene`: with per-tick scene poses, for a viewer or a recording."""
    from dsteleop.app.plants.kitchen import simulated_kitchen, task_options_from_meta
    from dsteleop.robot.description import description_from_record, load_description

    desc = (
        description_from_record(meta.get("robot"))
        if robot == "simulated"
        else load_description(robot)
    )
    recorded = meta.get("dims")
    if recorded is not None and len(recorded) - 6 != len(desc.fingers):
        raise InputError(
            f"the session's hand drove {len(recorded) - 6} robot fingers, robot {desc.name!r} "
            f"has {len(desc.fingers)}: replay it on a robot with as many (--robot), or "
            "re-track its video (--retrack)"
        )
    options = task_options_from_meta(meta.get("plant", {}))
    if robot != "simulated":  # another robot stands the scene where it reaches it
        options["placement"] = None
    from dsteleop.robot.reach import require_reachable

    require_reachable(desc, placement=options["placement"])  # else one line, exit 2
    return simulated_kitchen(desc, export_scene=export_scene, **options)


def replay_session(
    session: Session, mode: Mode, robot: RobotChoice = "simulated", sink: RunSink | None = None
) -> Trace:
    """Re-run the session's recorded hand input through a fresh loop in `mode`.

    Args:
        session: the session.
        mode: arbitration mode of the replay.
        robot: "simulated" (a fresh PyBullet robot and task, closed loop: the session's
            robot), a robot description's name or file (likewise, that robot), or
            "recorded" (the robot states the session recorded, open loop).
        sink: gets the run's records (and the scene, with per-tick poses) when it ends.
    """
    from dsteleop.app.plants.recorded import recorded_pair

    hand = RecordedHandInput(session.records, f"replay of {session.name}")
    world: tuple[Robot, Task] = (
        recorded_pair(session)
        if robot == "recorded"
        else simulated_world(session.meta, export_scene=sink is not None, robot=robot)
    )
    return run_headless(
        session.name,
        hand,
        [r.t_s for r in session.records],
        session_config(session, mode),
        world,
        session.history,
        sink,
    )


def as_recorded(session: Session) -> Trace:
    """The session's own ticks, as it happened."""
    cfg = session_config(session, None)
    F = len(session.dims) - 6
    return Trace.of(session.name, cfg.mode, session.records, cfg.arbitration.v_max(F))


# --- metrics --------------------------------------------------------------------------------


def belief_of(trace: Trace) -> dict[str, Any] | None:
    """The run's belief counts (`app.replay.belief.belief_metrics`), None when told."""
    if not any(b is not None for b in trace.beliefs):
        return None
    dt = float(np.median(np.diff(trace.t_s))) if len(trace) > 1 else 1.0 / 30.0
    return belief_metrics(trace.t_s.tolist(), trace.beliefs, trace.grasped, trace.dims, dt)


def action_counts(trace: Trace) -> dict[str, int]:
    """The arbitrated ticks' actions the action metrics counted, and the idle ones they
    skipped (both metrics skip the same)."""
    cos = metrics.summarise_cosines(metrics.cosine_distances(metric_table.replay_products(trace)))
    return {"actions": int(cos.n_actions), "skipped_idle": int(cos.n_skipped)}


def metric_values(trace: Trace) -> dict[str, Any]:
    """One run's value of every metric of the table (app/study/metric_table.py) and of its
    variant, in the table's order: success, time, cosine distance (the paper's sum; the mean
    per action beside it) and agreement over the arbitrated ticks, the action metrics in
    v_max units, both skipping the same idle actions."""
    out: dict[str, Any] = {}
    for m in metric_table.table():
        out[m.name] = m.replay(trace)
        if m.variant is not None:
            out[metric_table.variant_key(m)] = m.variant.replay(trace)
    return out


def is_censored(trace: Trace) -> bool:
    """The run's time is a bound, not a completion time: it ended without an outcome, or by
    the task's timeout."""
    return trace.outcome is None or trace.outcome.reason == "timeout"


#: Statistics over fewer episodes than this a mode are reported, and flagged as not
#: meaningful (a chi-squared or t-test on a handful of trials says nothing).
MIN_EPISODES = 5


class Run(NamedTuple):
    """One replay of one episode (or one video) in one mode.

    Attributes:
        name: the episode's name (`SESSION/epN`), or the video's.
        session: the session's (or video's) name.
        episode: the recorded episode (None for a video: one run, counted).
        recorded_s: its recorded length [s].
        trace: the replay.
    """

    name: str
    session: str
    episode: Episode | None
    recorded_s: float
    trace: Trace


#: What a replay's numbers are: "open" (a recorded hand replayed: it never saw the robot it
#: now drives, so it corrects nothing that robot does) or "closed" (`as_recorded`: the
#: sessions as the operator ran them, watching that robot).
LOOP_NOTES = {
    "open": "open loop: recorded hands replayed against a robot they never saw, so they "
    "correct nothing it does; differences between modes are not what an operator using each "
    "mode would achieve (compare the study's open-loop table)",
    "closed": "closed loop: the sessions as the operator ran them",
}


def loop_kind(as_recorded: bool) -> str:
    """ "closed" for the sessions as recorded, "open" for any replay (`LOOP_NOTES`)."""
    return "closed" if as_recorded else "open"


def episode_summaries(runs: Sequence[Run]) -> list[dict[str, Any]]:
    """One entry per episode (in order of first appearance) with every mode's metrics.

    A recorded episode counts when it ended with an outcome (`Episode.counted`); a video
    (no recorded episode) counts when every mode's run of it reached an outcome: one that
    ended first (the clip ended before the task) is listed, never counted as a failure
    (`end`: "video ended before the outcome")."""
    grouped: dict[str, list[Run]] = {}
    for r in runs:
        grouped.setdefault(r.name, []).append(r)
    out = []
    for name, group in grouped.items():
        first = group[0]
        ep = first.episode
        entry = session_summary(name, first.recorded_s, [r.trace for r in group])
        video_done = all(r.trace.outcome is not None for r in group)
        entry.update(
            session=first.session,
            episode=None if ep is None else ep.index,
            end=(
                ("video" if video_done else "video ended before the outcome")
                if ep is None
                else ep.end
            ),
            counted=video_done if ep is None else ep.counted,
            recorded_outcome=None if ep is None or ep.outcome is None else ep.outcome.reason,
        )
        out.append(entry)
    return out


def session_summary(name: str, recorded_s: float, traces: Sequence[Trace]) -> dict[str, Any]:
    """The metrics of one episode (or video) in each mode it was replayed in."""
    modes: dict[str, Any] = {}
    for tr in traces:
        alpha = tr.step.alpha
        mean_alpha = {
            d: finite(np.nanmean(alpha[tr.arbitrated, i])) if tr.arbitrated.any() else None
            for i, d in enumerate(tr.dims)
        }
        row: dict[str, Any] = {}
        for key, value in metric_values(tr).items():
            row[key] = value
            if key == "success":
                row["outcome"] = tr.outcome_name
            elif key == "time_s":
                row["censored"] = is_censored(tr)
        modes[tr.mode.value] = {
            **row,
            **action_counts(tr),
            "mean_alpha": mean_alpha,
            "arbitrated_ticks": int(tr.arbitrated.sum()),
        }
        belief = belief_of(tr)
        if belief is not None:
            modes[tr.mode.value]["belief"] = belief
    return {"name": name, "duration_s": round(recorded_s, 4), "modes": modes}


def aggregate(
    entries: Sequence[dict[str, Any]], modes: Sequence[str]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Per-mode aggregates over the counted episodes (those that ended with an outcome, and
    videos whose every run reached one) and the paper's tests between modes, each with its n
    and whether it is meaningful (`MIN_EPISODES` a mode at least)."""
    agg: dict[str, Any] = {}
    per: dict[str, dict[str, list[float]]] = {}
    counted = [e for e in entries if e.get("counted", True)]
    table = metric_table.table()
    n_runs: dict[str, int] = {}
    for mode in modes:
        rows = [s["modes"][mode] for s in counted if mode in s["modes"]]
        n_runs[mode] = len(rows)
        per[mode] = {m.name: _values(m, rows) for m in table}
        out: dict[str, Any] = {
            "n": len(rows),
            "excluded": sum(1 for e in entries if mode in e["modes"]) - len(rows),
        }
        for m in table:
            out.update(_summary(m, per[mode][m.name], rows))
        out["skipped_idle"] = sum(int(r.get("skipped_idle", 0)) for r in rows)
        agg[mode] = out
        beliefs = aggregate_beliefs([r.get("belief") for r in rows])
        if beliefs is not None:
            agg[mode]["belief"] = beliefs
    tests: dict[str, Any] = {}
    for i, a in enumerate(modes):
        for b in modes[i + 1 :]:
            pa, pb = per[a], per[b]
            na, nb = n_runs[a], n_runs[b]
            entry: dict[str, Any] = {"n": [na, nb], "meaningful": min(na, nb) >= MIN_EPISODES}
            if not entry["meaningful"]:
                entry["note"] = (
                    f"{a} vs {b}: n = {na} and {nb} episodes; fewer than {MIN_EPISODES} a "
                    "mode: the tests below are not meaningful"
                )
            for m in table:
                entry.update(_tests(m, counted, a, b, pa[m.name], pb[m.name]))
            tests[f"{a}_vs_{b}"] = entry
    return agg, tests


def _values(m: metric_table.Metric, rows: Sequence[dict[str, Any]]) -> list[float]:
    """A metric's values over runs that have one: a rate's 0/1, a log metric's positive
    values, a linear one's values that are not None."""
    if m.scale == "rate":
        return [float(bool(r[m.name])) for r in rows]
    if m.scale == "log":
        return [r[m.name] for r in rows if r[m.name] and r[m.name] > 0]
    return [r[m.name] for r in rows if r[m.name] is not None]


def _summary(
    m: metric_table.Metric, x: Sequence[float], rows: Sequence[dict[str, Any]]
) -> dict[str, Any]:
    """One mode's aggregate of the metric `m` over its runs' values `x`: a rate's estimate
    (`success_rate`); a log metric's geometric mean (and the censored runs beside the
    time); a linear one's geometric mean (the paper's Table I) with its interval; both with
    the arithmetic mean beside, labelled, and a variant's mean."""
    if m.scale == "rate":
        sr = metrics.success_rate(int(sum(x)), len(x)) if x else None
        return {m.summary_key: None if sr is None else jsonable(sr)}
    out: dict[str, Any] = {}
    if m.scale == "log":
        out[m.name] = jsonable(metrics.geometric_mean(x)) if x else None
    else:
        g = _geometric(x)
        out[m.name] = None if g is None else g.mean
        out[f"{m.name}_ci95"] = None if g is None else [g.ci_low, g.ci_high]
    out[f"{m.name}_arithmetic_mean"] = finite(np.mean(x)) if x else None
    if m.name == "time_s":  # which of the times are bounds, not completion times
        cen = sum(bool(r.get("censored", False)) for r in rows)
        out["censored"] = {"count": cen, "share": cen / len(rows) if rows else None}
    if m.variant is not None:
        k = metric_table.variant_key(m)
        v = [r[k] for r in rows if r.get(k) is not None]
        out[k] = finite(np.mean(v)) if v else None
    return out


def _tests(
    m: metric_table.Metric,
    counted: Sequence[dict[str, Any]],
    a: str,
    b: str,
    xa: Sequence[float],
    xb: Sequence[float],
) -> dict[str, Any]:
    """The paper's tests of one metric between modes a and b: a rate's McNemar test on the
    episodes run in both and its N-1 chi-squared test; a t test of the others (of the logs
    for a log metric), each where there are values."""
    out: dict[str, Any] = {}
    if m.scale == "rate":
        both = [
            (bool(e["modes"][a][m.name]), bool(e["modes"][b][m.name]))
            for e in counted
            if a in e["modes"] and b in e["modes"]
        ]
        if both:
            first, second = zip(*both, strict=True)
            out[f"{m.test_key}_mcnemar"] = jsonable(metrics.mcnemar(first, second))
        if xa and xb:
            out[f"{m.test_key}_n1_chi2"] = jsonable(
                metrics.n1_chi_squared(int(sum(xa)), len(xa), int(sum(xb)), len(xb))
            )
        return out
    if len(xa) >= 2 and len(xb) >= 2:
        ya, yb = (np.log(xa), np.log(xb)) if m.scale == "log" else (np.asarray(xa), np.asarray(xb))
        out[f"{m.test_key}_ttest"] = jsonable(metrics.t_test(ya, yb))
    return out


def _geometric(x: Sequence[float]) -> metrics.GeometricMean | None:
    """The geometric mean of `x` with its interval; None when empty or a value is <= 0."""
    if not x or min(x) <= 0:
        return None
    return metrics.geometric_mean(x)


#: Bins per axis of the Fig. 8 histograms of replays (x, y, z positions).
FIG8_BINS = 16


def divergences(traces: Sequence[Trace]) -> dict[str, Any]:
    """Fig. 8's Jensen-Shannon divergences over replays: per mode, a histogram of the hand's
    and one of the robot's (x, y, z) positions over the arbitrated ticks of every run in that
    mode (`FIG8_BINS` per axis over the box holding every point), then the paper's pairs
    (`app.study.summary.fig8_divergences`)."""
    from dsteleop.app.study.summary import fig8_divergences

    pts: dict[str, tuple[list[Array], list[Array]]] = {}
    for tr in traces:
        h, r = pts.setdefault(tr.mode.value, ([], []))
        h.append(tr.p_human[tr.arbitrated])
        r.append(tr.p_robot[tr.arbitrated])
    every = [p for h, r in pts.values() for p in (*h, *r) if p.size]
    every = [p[np.isfinite(p).all(-1)] for p in every]
    every = [p for p in every if p.size]
    if not every:
        return fig8_divergences({}, {})
    allp = np.concatenate(every)
    lo, hi = allp.min(0), allp.max(0)
    ranges = np.stack([lo, np.maximum(hi, lo + 1e-6)], -1)

    def hist(parts: list[Array]) -> NDArray[np.int64]:
        if not parts:
            return np.zeros((FIG8_BINS,) * 3, dtype=np.int64)
        return metrics.trajectory_histogram(np.concatenate(parts), FIG8_BINS, ranges)

    return fig8_divergences(
        {m: hist(h) for m, (h, _) in pts.items()}, {m: hist(r) for m, (_, r) in pts.items()}
    )


def test_notes(tests: dict[str, Any]) -> list[str]:
    """The notes of the tests that are not meaningful, to say beside the results."""
    return [str(t["note"]) for t in tests.values() if not t.get("meaningful", True)]
