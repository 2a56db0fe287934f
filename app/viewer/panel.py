"""The 2-D part of the browser view: gauges, status, the alpha plot and the camera image.

Pure functions from a `TickRecord` to what viser shows (HTML strings, arrays, an RGB image),
so they are tested without a server. The stylesheet and the HTML templates are files in
`web_assets/` (installed as `dsteleop.web_assets`). Colour code, everywhere: the operator is
blue, the robot orange. Each dimension's gauge is a bar whose orange share is alpha (the
robot's authority) and whose blue share is 1 - alpha (the operator's); ticks on the bar mark
P(H) (blue), P(R) (orange) and B (black), and the numbers follow, the last the robot's
confidence c_i in that dimension of its goal (a goal it infers, `--goal infer`; "-" when it
is told). Every gauge row carries its values as `data-*` attributes (`data-dim`,
`data-alpha`, `data-ph`, `data-pr`, `data-b`, `data-c`) so that a test, or an operator's own
tooling, can read them from the page. Above the gauges, the robot's belief over its goal
candidates: one bar per candidate (`belief_html`: `data-name`, `data-p`, `data-map` on each
row), or one line saying which goal it was told.

What the marks are (docs/METHOD.md): P(H) is the expected control allocation of the
operator's own pose, eq (4)-(5): the robot's share alpha that the hand's distance from the
goal, relative to the segment's length, would imply (1 at the goal); P(R) the same for the
robot's pose; B the willingness of eq (7), near 1 when the operator's expected speed change
psi_human is of the size the robot's psi_robot expects and towards 0 when it is far smaller or
larger; alpha = P(H) + (P(R) - P(H)) B, eq (8).

Besides the gauges: the source in the status line (`source_label`), a tally of the trials
since the page's session started (`TrialTally`), and what each hand motion does to the robot
(`mapping_rows`, read from the workspace mapping's own axes).
"""

from __future__ import annotations

import functools
import html
import importlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from string import Template
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app import sources
from dsteleop.app.ports import HumanInput
from dsteleop.app.session.schema import RecordingStatus, Status, TickRecord
from dsteleop.arbitration import ArbitrationStep
from dsteleop.errors import ConfigError
from dsteleop.tracking.mapping import MappingConfig
from dsteleop.tracking.sources import SourceSpec

Array = NDArray[np.float64]
Image = NDArray[np.uint8]

GREEN, AMBER, RED, GREY = "#1f9d55", "#d68910", "#c0392b", "#7f8c8d"
#: Reasons of a source that has no more input (`HandInput.end_reason`): shown as "ended".
ENDED_REASONS = ("video ended", "recording ended", "script ended")
# One colour per dimension in the plot: translation, rotation, fingers.
DIM_COLOURS: tuple[str, ...] = (
    "#d62728", "#2ca02c", "#1f77b4",  # x y z
    "#ff7f0e", "#9467bd", "#8c564b",  # roll pitch yaw
    "#e377c2", "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939",  # fingers
)  # fmt: skip
#: The camera image fits this box [px] (width, height) whatever its orientation: a portrait
#: phone frame must not push the controls below it off the screen.
CAMERA_BOX_PX = (320, 300)
#: The alpha plot's axes, with their units: labels short enough for the plot's height (a
#: longer y label is cut at both ends), the rest said in `PLOT_CAPTION`.
PLOT_AXES: tuple[dict[str, Any], ...] = (
    {"label": "t [s]", "labelSize": 18},
    {"label": "alpha (1 = robot)", "labelSize": 18, "size": 36},
)
#: Said above the plot, in words.
PLOT_CAPTION = (
    "alpha per dimension over the last 10 s: 0 the operator alone, 1 the robot alone "
    "(the colour of each line is named below it)"
)
#: Why the Mode dropdown starts at DS: the page's hint on that control (viser shows it on
#: hovering the label). The figures are docs/operator.md's "The demo with inferred goals"
#: (`scripts/demo_goals.py --goal infer --seeds 0-19`, every mode); this is the one place the
#: page and tests/test_viewer.py read it from.
MODE_HINT = (
    "DS is the default: with inferred goals (the demo, seeds 0-19) DSC succeeded in 18 of 20 "
    "(13.3 s) and DS in 13 (12.9 s); over seeds 0-59, 53 against 47 of 60, a difference that "
    "is not significant on the same seeds (McNemar exact p = 0.15), and in the study's objects "
    "world DSC ties DS in 3 of its 5 cells. Every mode's figures: docs/operator.md, "
    '"The demo with inferred goals".'
)
#: The plot's legend: the dimensions' names and colours; no values (uPlot shows values only
#: under a cursor and "--" otherwise).
PLOT_LEGEND: dict[str, Any] = {"show": True, "live": False}
# MediaPipe Hands' 21-landmark skeleton (wrist 0; thumb 1-4; index 5-8; ...; little 17-20).
HAND_CONNECTIONS: tuple[tuple[int, int], ...] = (
    (0, 1), (1, 2), (2, 3), (3, 4), (0, 5), (5, 6), (6, 7), (7, 8), (5, 9), (9, 10),
    (10, 11), (11, 12), (9, 13), (13, 14), (14, 15), (15, 16), (13, 17), (0, 17), (17, 18),
    (18, 19), (19, 20),
)  # fmt: skip


@functools.lru_cache(maxsize=16)
def asset(name: str) -> str:
    """A file of web_assets/ (the installed package data), as text."""
    return resources.files("dsteleop.web_assets").joinpath(name).read_text(encoding="utf-8")


def style_html() -> str:
    """The stylesheet as an HTML block (sent once; the updates then carry class names)."""
    return f"<style>{asset('dsteleop.css')}</style>"


def _template(name: str) -> Template:
    return Template(asset(name).strip())


def _pct(v: float) -> str:
    return f"{100.0 * float(np.clip(v, 0.0, 1.0)):.1f}%"


def _num(v: float) -> str:
    return "nan" if not math.isfinite(float(v)) else f"{float(v):.3f}"


def _two(v: float) -> str:
    return "nan" if not math.isfinite(float(v)) else f"{float(v):.2f}"


def gauge_row(
    dim: str, alpha: float, p_h: float, p_r: float, b: float, c: float | None = None
) -> str:
    """One dimension's gauge: alpha bar with P(H), P(R), B ticks, and the four numbers, then
    the robot's confidence `c` in the dimension (None: a goal it is told, shown "-")."""
    a = float(alpha) if math.isfinite(float(alpha)) else 0.0
    return _template("gauge_row.html").substitute(
        c_attr="" if c is None else _num(c),
        c="-" if c is None else _two(c),
        dim=html.escape(dim),
        alpha_attr=_num(alpha),
        ph_attr=_num(p_h),
        pr_attr=_num(p_r),
        b_attr=_num(b),
        who="robot" if a > 0.5 else "operator",
        alpha=f"{a:.2f}",
        alpha_pct=_pct(a),
        ph_pct=_pct(p_h),
        pr_pct=_pct(p_r),
        b_pct=_pct(b),
        ph=_two(p_h),
        pr=_two(p_r),
        b=_two(b),
    )


def gauges_html(record: TickRecord, step: ArbitrationStep | None) -> str:
    """All per-dimension gauges of a tick (of `step`: the record's, or the last one shown
    while the arbitration does not run; zeros before the first)."""
    D = len(record.dims)
    zeros = np.zeros(D)
    a, h, r, b = (
        (step.alpha, step.P_human, step.P_robot, step.B) if step is not None else (zeros,) * 4
    )
    c = None if record.belief is None else record.belief.confidence
    rows = [
        gauge_row(
            d, float(a[i]), float(h[i]), float(r[i]), float(b[i]), None if c is None else c[i]
        )
        for i, d in enumerate(record.dims)
    ]
    head = asset("gauges_head.html").strip()
    return f'<div class="dst-gauges" data-tick="{int(record.k)}">{head}{"".join(rows)}</div>'


def belief_html(record: TickRecord | None, told: str = "") -> str:
    """The robot's belief over its goal candidates: one bar per candidate, the MAP (the goal
    it seeks) in bold, with the joint confidence (`data-names`, `data-map`, `data-c-joint` on
    the block; `data-name`, `data-p`, `data-map` on each row); without a belief, one line
    saying the goal is told (`told`: which) or that there is none (the task is done)."""
    belief = None if record is None else record.belief
    if belief is None:
        said = (
            f"robot told its goal: {html.escape(told)}"
            if told
            else "robot told its goal (Utensil menu; infer: it infers it from the hand)"
        )
        return f'<div class="dst-belief" data-names="" data-map="">{said}</div>'
    rows = "".join(
        f'<div class="dst-belief-row" data-name="{html.escape(n)}" data-p="{_num(p)}" '
        f'data-map="{int(k == belief.map_index)}"><span class="dst-belief-name">'
        f'{html.escape(n)}</span><div class="dst-belief-bar"><div class="dst-belief-fill" '
        f'style="width:{_pct(p)}"></div></div><span class="dst-num">{_two(p)}</span></div>'
        for k, (n, p) in enumerate(zip(belief.names, belief.probability, strict=True))
    )
    names = html.escape(",".join(belief.names))
    return (
        f'<div class="dst-belief" data-names="{names}" data-map="{html.escape(belief.map_name)}"'
        f' data-c-joint="{_num(belief.confidence_joint)}"><b>Goal inferred</b> (belief; the '
        f"robot seeks <b>{html.escape(belief.map_name)}</b>, confidence "
        f"{_two(belief.confidence_joint)}){rows}</div>"
    )


def _timing_items(
    timing: Mapping[str, float], rate_hz: float | None, jitter_max_ms: float | None
) -> list[tuple[str, str]]:
    out = []
    if rate_hz is not None:
        out.append(("loop", f"{rate_hz:.1f} Hz"))
    elif timing.get("rate_hz") is not None:
        out.append(("loop (set)", f"{timing['rate_hz']:.0f} Hz"))
    if jitter_max_ms is not None:
        out.append(("jitter max 1 s", f"{jitter_max_ms:.1f} ms"))
    elif timing.get("jitter_ms") is not None:
        out.append(("jitter", f"{timing['jitter_ms']:.1f} ms"))
    if timing.get("tick_ms") is not None:
        out.append(("tick", f"{timing['tick_ms']:.1f} ms"))
    for key, label in (
        ("capture_to_commanded_ms", "latency"),
        ("capture_to_tracked_ms", "tracking"),
    ):
        v = timing.get(key)
        if v is not None and math.isfinite(v):
            out.append((label, f"{v:.0f} ms"))
    if timing.get("overruns"):
        out.append(("overruns", f"{int(timing['overruns'])}"))
    share = timing.get("overrun_share")
    if share:  # the share of the last 10 s of ticks that started a period late or more
        out.append(("late 10 s", f"{100 * share:.0f} %"))
    return out


@dataclass(frozen=True)
class StatusView:
    """What the status line says about a tick: a word, its detail and its colour.

    Attributes:
        word: `tracking` (the operator's hand drives the robot), `assist` (no hand; the
            robot goes on to its goal), `lost` (no usable hand: the robot halts), `stopped`
            (the operator's stop is latched: the robot halts until Resume), `ended` (the
            video or recording has no more frames), `finished` (the task has its outcome;
            the detail says which).
        detail: the reason or the outcome ("no hand", "success (in_bin)"), or "".
        colour: of the dot and the word: green tracking and success, amber assist, red
            lost, stopped and failure, grey ended.
    """

    word: str
    detail: str
    colour: str


def status_view(record: TickRecord) -> StatusView:
    """The status of a tick as the page shows it (`StatusView`)."""
    if record.status is Status.FINISHED:
        o = record.outcome
        return StatusView("finished", record.reason, GREEN if o is not None and o.success else RED)
    if record.status is Status.TRACKING:
        return StatusView("tracking", "", GREEN)
    if record.status is Status.ASSIST:
        return StatusView("assist", record.reason, AMBER)
    if record.stopped:
        return StatusView("stopped", RESUME_HINT, RED)
    if record.reason in ENDED_REASONS:
        return StatusView("ended", record.reason, GREY)
    return StatusView("lost", record.reason, RED)


#: The keys of the page's Stop and Resume (viser commands: also in its palette, Ctrl+K).
STOP_KEY, RESUME_KEY = "Escape", "Shift+R"
#: What the status line says while the operator's stop is latched.
RESUME_HINT = f"the robot halts until Resume ({RESUME_KEY})"


def stop_html(stopped: bool) -> str:
    """The stop indicator under the Stop and Resume buttons: a red banner while the
    operator's stop is latched, else a line naming the keys (`data-stopped` 1 or 0)."""
    if stopped:
        return (
            '<div class="dst-stop" data-stopped="1">ROBOT STOPPED &mdash; press Resume '
            f"({RESUME_KEY}) to drive it again</div>"
        )
    return (
        f'<div class="dst-stop" data-stopped="0">Stop ({STOP_KEY}) halts the robot '
        f"as a lost hand does, until Resume ({RESUME_KEY})</div>"
    )


def _clock(seconds: float) -> str:
    s = max(0, int(seconds))
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
    )


def recording_html(rec: RecordingStatus | None) -> str:
    """The recording indicator: a red dot, the elapsed time and the episodes ("" when not
    recording)."""
    if rec is None:
        return '<div class="dst-rec-off" data-recording="">not recording</div>'
    current = "between episodes" if rec.episode is None else f"episode {rec.episode + 1}"
    folder = html.escape(rec.folder)
    return (
        f'<div class="dst-rec" data-recording="{folder}" data-elapsed-s="{rec.elapsed_s:.1f}" '
        f'data-episodes="{rec.episodes}" title="recording into {folder}">'
        f'<span class="dst-rec-dot"></span><b>REC</b> {_clock(rec.elapsed_s)} &middot; '
        f"{current} &middot; {rec.episodes} ended</div>"
    )


def source_label(spec: SourceSpec) -> str:
    """What drives the hand, in the status line's words, as its source's plug-in says
    (`app.sources`: `demo` (the built-in synthetic operator: no camera), `camera N`,
    `video NAME` (the file's name), `images NAME`, `synthetic hand`), or the spec itself
    for a source no plug-in knows."""
    try:
        return sources.kind(spec.kind).label(spec)
    except ConfigError:
        return str(spec)


#: What the status line adds to the source label of the demo.
DEMO_NOTE = "synthetic operator, no camera"


def status_html(
    record: TickRecord,
    viewer: Mapping[str, Any] | None = None,
    rate_hz: float | None = None,
    jitter_max_ms: float | None = None,
    source: str = "",
    info: Mapping[str, str] | None = None,
) -> str:
    """Source, mode, tracking state and reason, timing, task phase and outcome, counters.

    The element also carries the tick's state as `data-*` attributes (for tests and an
    operator's tooling): status, reason, mode, phase, outcome, tick, rate, `data-stopped`
    (1 while the operator's stop is latched), `data-cmd-mps` (the commanded palm speed
    |U_cmd[:3]| [m/s]) and `data-palm-m` (the achieved palm position x,y,z [m]).

    Args:
        record: the tick shown.
        viewer: the view's own counters (tabs, skipped records).
        rate_hz: the loop rate measured from recent ticks [Hz], if known.
        jitter_max_ms: the largest start-time jitter of the last second's ticks [ms].
        source: what drives the hand (`source_label`), "" if not known.
        info: fixed facts about the session shown after the mode (name -> text), e.g. the
            operator's impairments.
    """
    view = status_view(record)
    detail = f" &mdash; {html.escape(view.detail)}" if view.detail else ""
    outcome = record.outcome
    outcome_text = "" if outcome is None else ("success" if outcome.success else "failure")
    out_col = {"success": "#1f9d55", "failure": "#c0392b"}.get(outcome_text, "#555")
    items: list[tuple[str, str]] = []
    if source:
        note = f" ({DEMO_NOTE})" if source == "demo" else ""
        items.append(("source", f"<b>{html.escape(source)}</b>{note}"))
    items += [
        ("mode", f"<b>{html.escape(record.mode.value)}</b>"),
        ("phase", html.escape(record.phase.value)),
    ]
    items += [(html.escape(k), html.escape(v)) for k, v in (info or {}).items()]
    if outcome_text:
        items.append(("outcome", f'<b style="color:{out_col}">{outcome_text}</b>'))
    timing = record.timing
    if record.status is not Status.TRACKING:  # no fresh frame: its age is no latency
        timing = {k: v for k, v in timing.items() if not k.startswith("capture_to")}
    items += _timing_items(timing, rate_hz, jitter_max_ms)
    if viewer:
        items += [(k, html.escape(str(v))) for k, v in viewer.items()]
    cells = " ".join(
        f'<span class="dst-item"><span class="dst-key">{k}</span> {v}</span>' for k, v in items
    )
    return _template("status.html").substitute(
        source=html.escape(source),
        status=html.escape(view.word),
        reason_attr=html.escape(view.detail),
        mode=html.escape(record.mode.value),
        phase=html.escape(record.phase.value),
        outcome=outcome_text,
        tick=int(record.k),
        rate="" if rate_hz is None else f"{rate_hz:.2f}",
        colour=view.colour,
        reason=detail,
        items=cells,
        recording=recording_html(record.recording),
        stopped="1" if record.stopped else "0",
        cmd_mps=f"{float(np.linalg.norm(record.U_cmd[:3])):.4f}",
        palm=",".join(f"{v:.4f}" for v in record.X_current.position),
    )


class AlphaHistory:
    """A fixed window of alpha samples for the time-series plot.

    Args:
        dims: dimension names (one series each).
        length: samples kept.
        window_s: the time span shown [s]: older samples are kept but not shown (when the
            view updates less often than planned, `length` samples span more).
    """

    def __init__(self, dims: Sequence[str], length: int, window_s: float = math.inf) -> None:
        self.dims = tuple(dims)
        self.window_s = float(window_s)
        self._t = np.full(length, np.nan)
        self._a = np.full((len(self.dims), length), np.nan)
        self._n = 0

    def push(self, t_s: float, alpha: Array) -> None:
        """Append one sample (the oldest falls out)."""
        self._t = np.roll(self._t, -1)
        self._a = np.roll(self._a, -1, axis=1)
        self._t[-1] = t_s
        self._a[:, -1] = np.asarray(alpha, dtype=np.float64)[: len(self.dims)]
        self._n += 1

    def data(self) -> tuple[Array, ...]:
        """(t, alpha_0, ..., alpha_D-1) over the filled part of the window and the last
        `window_s`, t from 0 at the oldest sample shown."""
        k = min(self._n, self._t.size)
        if k:
            k = int(np.count_nonzero(self._t[-k:] >= self._t[-1] - self.window_s))
        t = self._t[-k:] - (self._t[-k] if k else 0.0)
        return (t, *(row[-k:] for row in self._a))


def legend_html() -> str:
    """What the gauges' bars and marks mean, as eq (4)-(8) define them (module docstring)."""
    return asset("gauge_legend.html").strip()


@dataclass(frozen=True)
class Trial:
    """One trial the page saw end: its number since the page started, and its outcome.

    Attributes:
        number: 1 for the first trial the view saw end.
        success: the utensil rests in the bin.
        reason: the task's outcome reason ("in_bin", "timeout", ...).
        time_s: from the trial's start (a task reset) to its outcome [s].
        mode: the arbitration mode at the outcome.
    """

    number: int
    success: bool
    reason: str
    time_s: float
    mode: str


class TrialTally:
    """The trials that ended since the view started, read from the tick records.

    A trial ends when a record first carries an outcome; the next one can end only after the
    task was reset (the outcome cleared, or the tick count restarted). Records the view
    skipped do not matter: an outcome stays on the records until the reset.
    """

    def __init__(self) -> None:
        self.trials: list[Trial] = []
        self._armed = True
        self._k = -1

    def observe(self, record: TickRecord) -> Trial | None:
        """Count the record's outcome if it ends a trial; the trial, or None."""
        if record.outcome is None or record.k < self._k:
            self._armed = True
        self._k = int(record.k)
        o = record.outcome
        if o is None or not self._armed:
            return None
        self._armed = False
        n = len(self.trials) + 1
        trial = Trial(n, bool(o.success), o.reason, float(o.time_s), record.mode.value)
        self.trials.append(trial)
        return trial

    @property
    def successes(self) -> int:
        return sum(t.success for t in self.trials)


def _trial_html(t: Trial) -> str:
    word = "success" if t.success else "failure"
    said = word if t.success else f"{word} ({html.escape(t.reason)})"
    return (
        f'<span class="dst-trial" data-number="{t.number}" data-outcome="{word}" '
        f'data-reason="{html.escape(t.reason)}" data-time-s="{t.time_s:.1f}" '
        f'data-mode="{html.escape(t.mode)}" style="color:{GREEN if t.success else RED}">'
        f"#{t.number} {said} {t.time_s:.1f} s {html.escape(t.mode)}</span>"
    )


def tally_html(tally: TrialTally, shown: int = 4) -> str:
    """The tally line: trials, successes, failures, mean success time, and the last `shown`
    trials with their outcome and time (newest first)."""
    n, ok = len(tally.trials), tally.successes
    times = [t.time_s for t in tally.trials if t.success]
    mean = f" &middot; mean success time {sum(times) / len(times):.1f} s" if times else ""
    head = (
        f"<b>Trials since start</b> {n}: {ok} success{'es' if ok != 1 else ''}, "
        f"{n - ok} failure{'s' if n - ok != 1 else ''}{mean}"
        if n
        else "<b>Trials since start</b> none ended yet"
    )
    rows = "".join(_trial_html(t) for t in reversed(tally.trials[-shown:]))
    return (
        f'<div class="dst-tally" data-trials="{n}" data-successes="{ok}" '
        f'data-failures="{n - ok}">{head}<div>{rows}</div></div>'
    )


#: A camera axis, signed, in the words of an operator facing a camera that looks at them
#: (mirror) or one that looks where they look: (axis, sign) -> (mirror, not mirror).
_HAND_WORDS: dict[tuple[int, int], tuple[str, str]] = {
    (0, 1): ("to your left", "to your right"),
    (0, -1): ("to your right", "to your left"),
    (1, 1): ("down", "down"),
    (1, -1): ("up", "up"),
    (2, 1): ("back, away from the camera", "forward, away from the camera"),
    (2, -1): ("forward, towards the camera", "back, towards the camera"),
}
_ROBOT_AXES = (("x", "forward"), ("y", "left"), ("z", "up"))


def mapping_rows(config: MappingConfig) -> tuple[tuple[str, str], ...]:
    """What each hand motion does to the robot: (hand, robot) rows, read from the mapping's
    camera-to-base rotation, scale and finger table (`tracking/mapping.py`)."""
    R = config.R_base_cam
    rows: list[tuple[str, str]] = []
    for i, (axis, word) in enumerate(_ROBOT_AXES):
        j = int(np.argmax(np.abs(R[i])))
        hand = _HAND_WORDS[(j, 1 if R[i, j] > 0 else -1)][0 if config.mirror else 1]
        rows.append((f"hand {hand}", f"robot +{axis} ({word}), x{config.scale[i]:g}"))
    for rot, (axis, word) in zip(("roll", "pitch", "yaw"), _ROBOT_AXES, strict=True):
        rows.append((f"turn the hand about the {word} axis", f"robot {rot} (about {axis})"))
    for robot, human in config.robot_fingers:
        src = " + ".join(human) + (" (mean)" if len(human) > 1 else "")
        rows.append((f"open / close {src}", f"robot {robot}"))
    return tuple(rows)


def mapping_html(config: MappingConfig | None) -> str:
    """The mapping help: a two-column table of `mapping_rows` (or a line saying the source
    is not a hand in front of a camera)."""
    if config is None:
        return '<div class="dst-note dst-mapping">this source has no hand-to-robot mapping</div>'
    side = "facing you (a mirror)" if config.mirror else "behind you, looking where you look"
    rows = "".join(
        f"<tr><td>{html.escape(h)}</td><td>&rarr; {html.escape(r)}</td></tr>"
        for h, r in mapping_rows(config)
    )
    return (
        f'<div class="dst-mapping"><b>Hand &rarr; robot</b> (camera {side}; motion relative '
        "to where the hand was at Calibrate)"
        f"<table>{rows}</table></div>"
    )


def plot_series(dims: Sequence[str]) -> tuple[dict[str, Any], ...]:
    """uPlot series for (t, alpha per dimension)."""
    series: list[dict[str, Any]] = [{"label": "t [s]"}]
    for k, d in enumerate(dims):
        series.append(
            {
                "label": d,
                "stroke": DIM_COLOURS[k % len(DIM_COLOURS)],
                "width": 1.5,
                "points": {"show": False},
            }
        )
    return tuple(series)


def _draw_landmarks(canvas: Image, landmarks: Array) -> None:
    cv2: Any = importlib.import_module("cv2")
    h, w = canvas.shape[:2]
    if not np.isfinite(landmarks[:, :2]).all():
        return
    pts = np.round(np.asarray(landmarks)[:, :2] * (w, h)).astype(int)
    for a, b in HAND_CONNECTIONS:
        if a < len(pts) and b < len(pts):
            cv2.line(
                canvas,
                tuple(int(v) for v in pts[a]),
                tuple(int(v) for v in pts[b]),
                (255, 255, 255),
                2,
                cv2.LINE_AA,
            )
    for p in pts:
        cv2.circle(canvas, (int(p[0]), int(p[1])), 3, (255, 140, 0), -1, cv2.LINE_AA)


def fit(width_px: int, height_px: int, box_px: tuple[int, int] = CAMERA_BOX_PX) -> tuple[int, int]:
    """(width, height) [px] of an image of this size scaled to fit `box_px`, aspect kept."""
    scale = min(box_px[0] / max(1, width_px), box_px[1] / max(1, height_px))
    return max(1, round(width_px * scale)), max(1, round(height_px * scale))


def camera_image(hand: HumanInput | None, box_px: tuple[int, int] = CAMERA_BOX_PX) -> Image | None:
    """A small RGB image of the tracked hand: the camera frame (or a grey canvas for
    sources without pixels, such as the demo operator) scaled to fit `box_px` (landscape or
    portrait), with the landmarks drawn. None when there is nothing to show."""
    sample = None if hand is None else hand.sample
    if sample is None:
        return None
    image, landmarks = sample.image, sample.landmarks_image
    if image is None and landmarks is None:
        return None
    cv2: Any = importlib.import_module("cv2")
    if image is not None:
        src = np.asarray(image)
        size = fit(src.shape[1], src.shape[0], box_px)
        small = cv2.resize(src, size, interpolation=cv2.INTER_AREA)
        canvas: Image = np.ascontiguousarray(small[:, :, ::-1])  # BGR -> RGB
    else:
        w, h = fit(sample.width_px or 640, sample.height_px or 480, box_px)
        canvas = np.full((h, w, 3), 60, dtype=np.uint8)
    if sample.detected and landmarks is not None:
        _draw_landmarks(canvas, np.asarray(landmarks, dtype=np.float64))
    return canvas
