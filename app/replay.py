"""Headless replay of recorded sessions (and videos) with the paper's metrics.

`dsteleop replay SESSION... --modes S,DS --out DIR` re-runs each session's recorded human
input through the loop, as fast as the machine allows, once per requested mode: the same
hand input at the same tick times, a fresh robot and task with the session's seed and goal
noise, so the modes are paired. `--as-recorded` recomputes the metrics of each session as
it happened instead. `--retrack` re-runs tracking on the session's video. A video file given
instead of a session is tracked and replayed as one.

Metrics per session and mode (DESIGN.md §4, paper Section IV-D), over the ticks where the
arbitration ran; actions are compared in units of each dimension's velocity limit (U / v_max),
so metres, radians and openness weigh alike:

    cosine distance  mean over actions of 1 - U_h.U_out / (|U_h| |U_out|)  (zero-norm skipped)
    agreement        mean over actions of [U_h.U_out > 0]
    success, time    the task's outcome and its duration [s]
    mean_alpha       per dimension

Across sessions: success rate (Laplace, adjusted-Wald CI), geometric-mean time (CI), and the
paper's tests between modes (N-1 chi-squared on success, t-tests on log time and on the
per-session cosine distance and agreement).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.cli_util import Progress, prepare_out_dir
from dsteleop.app.hand_input import HandInput, HumanInput, RecordedHandInput, RecordedInput
from dsteleop.app.loop import LoopConfig, Plant, PlantStep, TeleopLoop, unpack
from dsteleop.app.observers import Snapshot
from dsteleop.app.recording import Session, is_session, read_session
from dsteleop.app.timing import ManualClock
from dsteleop.arbitration import HandState, Mode, OperatorHistory
from dsteleop.errors import DsteleopError

log = logging.getLogger(__name__)
Array = NDArray[np.float64]

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v"}


@dataclass(frozen=True)
class Trace:
    """Per-tick arrays of one run (recorded or replayed), for metrics and plots."""

    name: str
    mode: str
    t_s: Array  # (T,)
    arbitrated: NDArray[np.bool_]  # (T,)
    alpha: Array  # (T, D)
    P_human: Array
    P_robot: Array
    B: Array
    U_human: Array
    U_out: Array
    p_human: Array  # (T, 3), NaN where no hand
    p_robot: Array  # (T, 3)
    outcome: str
    time_s: float
    dims: tuple[str, ...]
    v_max: Array  # (D,)


def _trace_from_records(
    name: str,
    mode: str,
    records: list[dict[str, Any]],
    dims: tuple[str, ...],
    v_max: Array,
    outcome: str,
) -> Trace:
    D = len(dims)
    T = len(records)
    nan = np.full((T, D), np.nan)
    arrays = {k: nan.copy() for k in ("alpha", "P_human", "P_robot", "B", "U_human", "U_out")}
    keys = {
        "alpha": "alpha",
        "P_human": "P_human",
        "P_robot": "P_robot",
        "B": "B",
        "U_human": "U_human",
        "U_out": "U_out",
    }
    arbitrated = np.zeros(T, dtype=bool)
    p_h = np.full((T, 3), np.nan)
    p_r = np.full((T, 3), np.nan)
    t = np.array([float(r["t"]) for r in records]) if records else np.zeros(0)
    for k, r in enumerate(records):
        arb = r.get("arb")
        if arb:
            arbitrated[k] = True
            for a, key in keys.items():
                arrays[a][k] = arb[key]
        hand = r.get("hand") or {}
        X = unpack(hand.get("X"))
        if X is not None:
            p_h[k] = X.position
        Xc = unpack(r.get("X_current"))
        if Xc is not None:
            p_r[k] = Xc.position
    duration = float(t[-1] - t[0]) if T > 1 else 0.0
    end = next((float(r["t"]) for r in records if r.get("outcome")), None)
    time_s = (end - float(t[0])) if (end is not None and T) else duration
    return Trace(
        name,
        mode,
        t - (t[0] if T else 0.0),
        arbitrated,
        **arrays,
        p_human=p_h,
        p_robot=p_r,
        outcome=outcome,
        time_s=time_s,
        dims=dims,
        v_max=v_max,
    )


def action_metrics(trace: Trace) -> dict[str, float | None]:
    """Cosine distance and agreement over the arbitrated ticks, in v_max units."""
    from dsteleop.arbitration import metrics

    m = trace.arbitrated
    U_h = trace.U_human[m] / trace.v_max
    U_o = trace.U_out[m] / trace.v_max
    cos = metrics.cosine_distance(U_h, U_o)
    agree = metrics.agreement(U_h, U_o)
    return {"cosine_distance": _num(cos.mean), "agreement": _num(agree.ratio)}


def _num(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# --- inputs from sessions and videos ------------------------------------------------------


def recorded_inputs(session: Session) -> list[RecordedInput]:
    """The mapped hand input the loop used at each recorded tick."""
    out: list[RecordedInput] = []
    for r in session.ticks:
        hand = r.get("hand")
        inp = None
        if hand is not None:
            inp = HumanInput(
                seq=int(hand["seq"]),
                t_capture_s=float(hand["t_capture"]),
                t_tracked_s=float(hand["t_tracked"]),
                X_human=unpack(hand.get("X")),
                reason=str(hand.get("reason", "")),
            )
        out.append(RecordedInput(float(r["t"]), inp))
    return out


def _session_config(session: Session, mode: Mode | None) -> LoopConfig:
    cfg = LoopConfig.from_dict(session.meta.get("loop", {}))
    return cfg if mode is None else LoopConfig.from_dict({**cfg.to_dict(), "mode": mode.value})


def run_headless(
    name: str,
    hand: HandInput,
    tick_times: list[float],
    cfg: LoopConfig,
    plant_meta: dict[str, Any],
    history: OperatorHistory | None = None,
    plant: Plant | None = None,
) -> Trace:
    """Run a fresh loop over `tick_times` (as fast as possible) and trace it; the plant is
    a fresh simulated one built from `plant_meta` unless one is given."""
    if plant is None:
        from dsteleop.app.plant import plant_from_meta

        plant = plant_from_meta(plant_meta)
    clock = ManualClock(tick_times[0] if tick_times else 0.0)
    loop = TeleopLoop(cfg, hand, plant, clock=clock, history=history)
    sub = loop.broadcaster.subscribe()
    snaps: list[Snapshot] = []
    try:
        for t in tick_times:
            clock.sleep_until(t)
            loop.tick(t)
            snap = sub.latest()
            assert snap is not None
            snaps.append(snap)
    finally:
        loop.close()
    v_max = cfg.arbitration.v_max(len(plant.finger_names))
    return _trace_from_snapshots(name, cfg.mode.value, snaps, loop.dims, v_max, loop.outcome)


def _trace_from_snapshots(
    name: str,
    mode: str,
    snaps: list[Snapshot],
    dims: tuple[str, ...],
    v_max: Array,
    outcome: str,
) -> Trace:
    T, D = len(snaps), len(dims)
    arbitrated = np.array([s.arbitrated for s in snaps], dtype=bool)

    def stack(attr: str) -> Array:
        out = np.full((T, D), np.nan)
        for k, s in enumerate(snaps):
            if s.arbitrated:
                out[k] = getattr(s, attr)
        return out

    t = np.array([s.t_s for s in snaps])
    p_h = np.array(
        [
            s.hand.X_human.position
            if s.hand is not None and s.hand.X_human is not None
            else [np.nan] * 3
            for s in snaps
        ]
    ).reshape(T, 3)
    p_r = np.array([s.X_current.position for s in snaps]).reshape(T, 3)
    end = next((s.t_s for s in snaps if s.outcome), None)
    t0 = float(t[0]) if T else 0.0
    duration = float(t[-1] - t0) if T > 1 else 0.0
    return Trace(
        name,
        mode,
        t - t0,
        arbitrated,
        alpha=stack("alpha"),
        P_human=stack("P_human"),
        P_robot=stack("P_robot"),
        B=stack("B"),
        U_human=stack("U_human"),
        U_out=stack("U_out"),
        p_human=p_h,
        p_robot=p_r,
        outcome=outcome,
        time_s=(end - t0) if end is not None else duration,
        dims=dims,
        v_max=v_max,
    )


class RecordedPlant:
    """The robot side of a session, played back: each tick returns what the robot and the
    task reported when the session was recorded (achieved state, phase, task events,
    outcome), whatever the loop commands.

    Replaying a session against its recorded robot is open loop: no physics runs, so the
    arbitration sees exactly the states it saw live, on any machine. It reproduces the
    recorded arbitration (in the recorded mode), or shows what another mode would have
    computed along the same robot path; it cannot show where another mode would have taken
    the robot (that is the simulated replay).
    """

    def __init__(self, session: Session, finger_names: tuple[str, ...]) -> None:
        self.finger_names = finger_names
        self._meta = dict(session.meta.get("plant", {}))
        self._ticks = session.ticks
        self._k = 0
        if not session.ticks or "X_reset" not in session.ticks[0]:
            raise DsteleopError(
                f"{session.folder}: recorded before robot states were recorded for replay "
                "(no X_reset); replay it against the simulated robot"
            )

    def _record(self) -> dict[str, Any]:
        if self._k >= len(self._ticks):
            raise DsteleopError("replay ran past the last recorded tick")
        return self._ticks[self._k]

    def reset(self, utensil: str | None = None) -> HandState:
        X = unpack(self._record().get("X_reset"))
        if X is None:
            raise DsteleopError(f"tick {self._k}: a reset that the recording does not hold")
        return X

    def goal(self) -> HandState | None:
        prev = self._ticks[self._k - 1] if self._k > 0 else None
        if prev is not None and prev.get("phase") == "done" and "X_reset" not in self._record():
            return None
        return unpack(self._record().get("X_goal"))

    def phase(self) -> str:
        return str(self._record().get("phase", ""))

    def apply(self, X_next: HandState) -> PlantStep:
        r = self._record()
        self._k += 1
        events = tuple(str(e) for e in r.get("events", []) if str(e).split(":")[0] in _TASK)
        X = unpack(r.get("X_current"))
        assert X is not None
        return PlantStep(
            X_current=X,
            phase=str(r.get("phase", "")),
            events=events,
            outcome=str(r.get("outcome", "")),
            segment_changed=any(e.split(":")[0] == "goal" for e in events),
        )

    def set_goal_noise(self, sigma_m: float) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return self._meta

    def scene_description(self) -> Any:
        return None

    def close(self) -> None:
        pass


_TASK = {"goal", "grasp", "release", "success", "failure"}


def replay_session(session: Session, mode: Mode, robot: str = "simulated") -> Trace:
    """Re-run the session's recorded hand input through a fresh loop in `mode`.

    Args:
        session: the session.
        mode: arbitration mode of the replay.
        robot: "simulated" (a fresh PyBullet robot and task, closed loop) or "recorded"
            (the robot states the session recorded, open loop: `RecordedPlant`).
    """
    hand = RecordedHandInput(recorded_inputs(session), f"replay of {session.name}")
    history = (
        OperatorHistory.from_dict(session.meta["operator_history"])
        if "operator_history" in session.meta
        else None
    )
    plant = None
    if robot == "recorded":
        dims = tuple(session.meta.get("dims", ()))
        plant = RecordedPlant(session, dims[6:])
    return run_headless(
        session.name,
        hand,
        [float(r["t"]) for r in session.ticks],
        _session_config(session, mode),
        session.meta.get("plant", {}),
        history,
        plant,
    )


def as_recorded(session: Session) -> Trace:
    cfg = _session_config(session, None)
    dims = tuple(session.meta.get("dims", []))
    F = len(dims) - 6
    outcome = str(
        session.meta.get("outcome")
        or next((r.get("outcome") for r in reversed(session.ticks) if r.get("outcome")), "")
        or ""
    )
    return _trace_from_records(
        session.name, cfg.mode.value, session.ticks, dims, cfg.arbitration.v_max(F), outcome
    )


# --- the command ----------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="SESSION",
        help="session folders, folders of sessions, or video files",
    )
    parser.add_argument(
        "--modes", default="S,DS", help="comma-separated modes to replay in (default S,DS)"
    )
    parser.add_argument(
        "--out", required=True, type=Path, help="output folder for metrics.json and plots"
    )
    parser.add_argument(
        "--as-recorded", action="store_true", help="metrics of the sessions as they happened"
    )
    parser.add_argument(
        "--retrack", action="store_true", help="re-run tracking on each session's video"
    )
    parser.add_argument(
        "--workers", type=int, default=min(2, os.cpu_count() or 1), help="parallel processes"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")


def _expand(inputs: list[str]) -> list[Path]:
    out: list[Path] = []
    for s in inputs:
        p = Path(s)
        if not p.exists():
            raise DsteleopError(f"not found: {p}")
        if p.is_dir() and not is_session(p):
            subs = sorted(q for q in p.iterdir() if q.is_dir() and is_session(q))
            vids = sorted(q for q in p.iterdir() if q.suffix.lower() in VIDEO_SUFFIXES)
            if not subs and not vids:
                raise DsteleopError(f"{p} holds no sessions (folders with meta.json) and no videos")
            out.extend(subs + vids)
        else:
            out.append(p)
    return out


def _work(item: tuple[str, tuple[str, ...], bool, bool]) -> list[dict[str, Any]]:
    """One input, all modes (runs in a worker process)."""
    path_s, modes, as_rec, retrack = item
    path = Path(path_s)
    if path.suffix.lower() in VIDEO_SUFFIXES:
        from dsteleop.app.video_session import replay_video

        traces, recorded_s = replay_video(path, [Mode.parse(m) for m in modes])
        return [{"trace": tr, "name": path.name, "recorded_s": recorded_s} for tr in traces]
    session = read_session(path)
    if as_rec:
        traces = [as_recorded(session)]
    elif retrack:
        from dsteleop.app.video_session import replay_retracked

        traces = replay_retracked(session, [Mode.parse(m) for m in modes])
    else:
        traces = [replay_session(session, Mode.parse(m)) for m in modes]
    return [_trace_dict(tr, session) for tr in traces]


def _trace_dict(tr: Trace, session: Session) -> dict[str, Any]:
    return {
        "trace": tr,
        "name": session.name,
        "recorded_s": float(tr.t_s[-1]) if len(tr.t_s) else 0.0,
    }


def session_summary(name: str, recorded_s: float, traces: list[Trace]) -> dict[str, Any]:
    modes: dict[str, Any] = {}
    for tr in traces:
        m = action_metrics(tr)
        mean_alpha = {
            d: _num(np.nanmean(tr.alpha[tr.arbitrated, i])) if tr.arbitrated.any() else None
            for i, d in enumerate(tr.dims)
        }
        modes[tr.mode] = {
            "success": tr.outcome == "success",
            "outcome": tr.outcome or "none",
            "time_s": round(tr.time_s, 4),
            **m,
            "mean_alpha": mean_alpha,
            "arbitrated_ticks": int(tr.arbitrated.sum()),
        }
    return {"name": name, "duration_s": round(recorded_s, 4), "modes": modes}


def aggregate(
    sessions: list[dict[str, Any]], modes: list[str]
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Per-mode aggregates over sessions and the paper's tests between modes."""
    from dsteleop.arbitration import metrics

    agg: dict[str, Any] = {}
    per: dict[str, dict[str, list[float]]] = {}
    for mode in modes:
        rows = [s["modes"][mode] for s in sessions if mode in s["modes"]]
        succ = [bool(r["success"]) for r in rows]
        times = [r["time_s"] for r in rows if r["time_s"] and r["time_s"] > 0]
        cos = [r["cosine_distance"] for r in rows if r["cosine_distance"] is not None]
        agr = [r["agreement"] for r in rows if r["agreement"] is not None]
        per[mode] = {"success": [float(x) for x in succ], "time": times, "cos": cos, "agr": agr}
        sr = metrics.success_rate(sum(succ), len(succ)) if succ else None
        gt = metrics.geometric_mean(times) if len(times) >= 1 else None
        agg[mode] = {
            "n": len(rows),
            "success_rate": None if sr is None else _dc(sr),
            "time_s": None if gt is None else _dc(gt),
            "cosine_distance": _num(np.mean(cos)) if cos else None,
            "agreement": _num(np.mean(agr)) if agr else None,
        }
    tests: dict[str, Any] = {}
    for i, a in enumerate(modes):
        for b in modes[i + 1 :]:
            key = f"{a}_vs_{b}"
            pa, pb = per[a], per[b]
            entry: dict[str, Any] = {}
            if pa["success"] and pb["success"]:
                entry["success_n1_chi2"] = _dc(
                    metrics.n1_chi_squared(
                        int(sum(pa["success"])),
                        len(pa["success"]),
                        int(sum(pb["success"])),
                        len(pb["success"]),
                    )
                )
            for name, k in (
                ("log_time_ttest", "time"),
                ("cosine_distance_ttest", "cos"),
                ("agreement_ttest", "agr"),
            ):
                xa, xb = pa[k], pb[k]
                if len(xa) >= 2 and len(xb) >= 2:
                    xa_, xb_ = (
                        (np.log(xa), np.log(xb))
                        if k == "time"
                        else (np.asarray(xa), np.asarray(xb))
                    )
                    entry[name] = _dc(metrics.t_test(xa_, xb_))
            tests[key] = entry
    return agg, tests


def _dc(obj: Any) -> Any:
    import dataclasses

    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {k: _dc(v) for k, v in dataclasses.asdict(obj).items()}
    if isinstance(obj, dict):
        return {k: _dc(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_dc(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return _num(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def run(args: argparse.Namespace) -> int:
    try:
        modes = [Mode.parse(m.strip()).value for m in args.modes.split(",") if m.strip()]
    except ValueError as exc:
        raise DsteleopError(str(exc)) from exc
    if not modes:
        raise DsteleopError("--modes is empty")
    if args.workers < 1:
        raise DsteleopError(f"--workers must be >= 1, got {args.workers}")
    paths = _expand(list(args.inputs))
    out = prepare_out_dir(Path(args.out))
    # Validate every input before the long work starts.
    for p in paths:
        if p.suffix.lower() not in VIDEO_SUFFIXES:
            read_session(p)
    t0 = time.perf_counter()
    # Work units: a recorded session replays once per mode, each mode its own unit (the
    # modes of one session run in parallel); a video or a re-tracked session is one unit
    # (tracked once, then run in every mode).
    items: list[tuple[int, tuple[str, tuple[str, ...], bool, bool]]] = []
    for i, p in enumerate(paths):
        whole = args.as_recorded or args.retrack or p.suffix.lower() in VIDEO_SUFFIXES
        units = [tuple(modes)] if whole else [(m,) for m in modes]
        for u in units:
            items.append((i, (str(p), u, bool(args.as_recorded), bool(args.retrack))))
    by_input: dict[int, list[dict[str, Any]]] = {}
    with Progress(len(items), sys.stderr, sys.stderr.isatty(), "replay", "runs") as bar:
        if args.workers == 1 or len(items) == 1:
            for i, it in items:
                by_input.setdefault(i, []).extend(_work(it))
                bar.advance()
        else:
            import dsteleop.app.plant  # noqa: F401  (loaded once; the forked workers share it)

            with ProcessPoolExecutor(max_workers=args.workers) as pool:
                for (i, _), res in zip(items, pool.map(_work, [it for _, it in items])):
                    by_input.setdefault(i, []).extend(res)
                    bar.advance()
    wall = time.perf_counter() - t0
    sessions = []
    all_traces = []
    for i in sorted(by_input):
        res = by_input[i]
        traces = [r["trace"] for r in res]
        all_traces.extend(traces)
        sessions.append(session_summary(res[0]["name"], res[0]["recorded_s"], traces))
    used_modes = sorted(
        {tr.mode for tr in all_traces}, key=lambda m: modes.index(m) if m in modes else 99
    )
    agg, tests = aggregate(sessions, used_modes)
    recorded = sum(s["duration_s"] for s in sessions)
    metrics_json = {
        "wall_s": round(wall, 3),
        "recorded_s": round(recorded, 3),
        "speed_x_realtime": round(recorded * (1 if args.as_recorded else len(modes)) / wall, 2)
        if wall > 0
        else None,
        "as_recorded": bool(args.as_recorded),
        "sessions": sessions,
        "modes": agg,
        "tests": tests,
    }
    (out / "metrics.json").write_text(
        json.dumps(_dc(metrics_json), indent=2, allow_nan=False) + "\n"
    )
    if not args.no_plots:
        from dsteleop.app.replay_plots import plot_traces

        plot_traces(all_traces, out)
    json.dump(
        {
            "metrics": str(out / "metrics.json"),
            "wall_s": metrics_json["wall_s"],
            "sessions": len(sessions),
        },
        sys.stdout,
    )
    sys.stdout.write("\n")
    return 0
