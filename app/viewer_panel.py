"""The 2-D part of the browser view: gauges, status, the alpha plot and the camera image.

Pure functions from a `Snapshot` to what viser shows (HTML strings, arrays, an RGB image),
so they are tested without a server. Colour code, everywhere: the operator is blue, the
robot orange. Each dimension's gauge is a bar whose orange share is alpha (the robot's
authority) and whose blue share is 1 - alpha (the operator's); ticks on the bar mark P(H)
(blue), P(R) (orange) and B (black), and the numbers follow. Every gauge row carries its
values as `data-*` attributes (`data-dim`, `data-alpha`, `data-ph`, `data-pr`, `data-b`) so
that a test, or an operator's own tooling, can read them from the page.
"""

from __future__ import annotations

import html
import importlib
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Image = NDArray[np.uint8]

HUMAN_HEX = "#2f7fd8"
ROBOT_HEX = "#e8702a"
B_HEX = "#222222"
STATUS_HEX = {"tracking": "#1f9d55", "assist": "#1f9d55", "lost": "#c0392b", "halted": "#c0392b"}
# One colour per dimension in the plot: translation, rotation, fingers.
DIM_COLOURS: tuple[str, ...] = (
    "#d62728",
    "#2ca02c",
    "#1f77b4",  # x y z
    "#ff7f0e",
    "#9467bd",
    "#8c564b",  # roll pitch yaw
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
    "#393b79",
    "#637939",  # fingers
)
CAMERA_WIDTH_PX = 320
# MediaPipe Hands' 21-landmark skeleton (wrist 0; thumb 1-4; index 5-8; ...; little 17-20).
HAND_CONNECTIONS: tuple[tuple[int, int], ...] = (
    (0, 1),
    (1, 2),
    (2, 3),
    (3, 4),
    (0, 5),
    (5, 6),
    (6, 7),
    (7, 8),
    (5, 9),
    (9, 10),
    (10, 11),
    (11, 12),
    (9, 13),
    (13, 14),
    (14, 15),
    (15, 16),
    (13, 17),
    (0, 17),
    (17, 18),
    (18, 19),
    (19, 20),
)


def _pct(v: float) -> str:
    return f"{100.0 * float(np.clip(v, 0.0, 1.0)):.1f}%"


def _num(v: float) -> str:
    return "nan" if not math.isfinite(float(v)) else f"{float(v):.3f}"


# Sent once (a <style> element in its own HTML block); the gauges then carry class names
# only, which keeps each 10 Hz update small.
GAUGE_CSS = f"""<style>
.dst-gauges {{ padding: 0 6px; }}
.dst-head, .dst-gauge {{ display: flex; align-items: center; gap: 4px; font-size: 11px; }}
.dst-head {{ font-size: 10px; color: #666; margin-bottom: 2px; }}
.dst-gauge {{ margin: 3px 0; }}
.dst-name {{ width: 40px; font-weight: 600; }}
.dst-num {{ width: 34px; text-align: right; font-variant-numeric: tabular-nums; }}
.dst-a {{ font-weight: 700; }}
.dst-h {{ color: {HUMAN_HEX}; }}
.dst-r {{ color: {ROBOT_HEX}; }}
.dst-bv {{ color: {B_HEX}; }}
.dst-bar {{ position: relative; height: 14px; flex: 1; min-width: 70px;
           background: {HUMAN_HEX}; border-radius: 3px; }}
.dst-fill {{ height: 100%; background: {ROBOT_HEX}; border-radius: 3px 0 0 3px; }}
.dst-tick {{ position: absolute; width: 3px; height: 6px; margin-left: -1px;
            border-radius: 1px; }}
.dst-tick-h {{ top: -3px; background: #0b3d91; }}
.dst-tick-r {{ top: 11px; background: #8a3a00; }}
.dst-tick-b {{ top: 4px; background: {B_HEX}; }}
.dst-status {{ padding: 2px 6px; font-size: 12px; line-height: 1.6; }}
.dst-item {{ white-space: nowrap; margin-right: 10px; }}
.dst-key {{ color: #777; }}
</style>"""


def gauge_row(dim: str, alpha: float, p_h: float, p_r: float, b: float) -> str:
    """One dimension's gauge: alpha bar with P(H), P(R), B ticks, and the four numbers."""
    a = float(alpha) if math.isfinite(float(alpha)) else 0.0
    who = "robot" if a > 0.5 else "operator"
    e = html.escape(dim)
    return (
        f'<div class="dst-gauge" data-dim="{e}" data-alpha="{_num(alpha)}" '
        f'data-ph="{_num(p_h)}" data-pr="{_num(p_r)}" data-b="{_num(b)}">'
        f'<span class="dst-name">{e}</span>'
        f'<div class="dst-bar" title="alpha {a:.2f}: {who} leads">'
        f'<div class="dst-fill" style="width:{_pct(a)}"></div>'
        f'<div class="dst-tick dst-tick-h" style="left:{_pct(p_h)}"></div>'
        f'<div class="dst-tick dst-tick-r" style="left:{_pct(p_r)}"></div>'
        f'<div class="dst-tick dst-tick-b" style="left:{_pct(b)}"></div></div>'
        f'<span class="dst-num dst-a">{a:.2f}</span><span class="dst-num dst-h">{p_h:.2f}</span>'
        f'<span class="dst-num dst-r">{p_r:.2f}</span><span class="dst-num dst-bv">{b:.2f}</span>'
        "</div>"
    )


def gauges_html(snap: Any) -> str:
    """All per-dimension gauges of a snapshot, with a header line (needs `GAUGE_CSS`)."""
    head = (
        '<div class="dst-head"><span class="dst-name">dim</span>'
        '<span style="flex:1"><b class="dst-r">robot</b> = &alpha; / '
        '<b class="dst-h">operator</b> = 1 - &alpha;</span>'
        '<span class="dst-num">&alpha;</span><span class="dst-num">P(H)</span>'
        '<span class="dst-num">P(R)</span><span class="dst-num">B</span></div>'
    )
    rows = [
        gauge_row(d, float(a), float(h), float(r), float(b))
        for d, a, h, r, b in zip(snap.dims, snap.alpha, snap.P_human, snap.P_robot, snap.B)
    ]
    return f'<div class="dst-gauges" data-tick="{int(snap.tick)}">{head}{"".join(rows)}</div>'


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
    return out


def status_html(
    snap: Any,
    viewer: Mapping[str, Any] | None = None,
    rate_hz: float | None = None,
    jitter_max_ms: float | None = None,
) -> str:
    """Mode, tracking state and reason, timing, task phase and outcome, viewer counters.

    Args:
        snap: the snapshot shown.
        viewer: the view's own counters (tabs, skipped snapshots).
        rate_hz: the loop rate measured from recent snapshots [Hz], if known.
        jitter_max_ms: the largest start-time jitter of the last second's snapshots [ms].
    """
    status = str(snap.status)
    colour = STATUS_HEX.get(status, "#555")
    reason = f" &mdash; {html.escape(str(snap.reason))}" if snap.reason else ""
    outcome = str(snap.outcome)
    out_col = {"success": "#1f9d55", "failure": "#c0392b"}.get(outcome, "#555")
    items = [
        ("mode", f"<b>{html.escape(str(snap.mode))}</b>"),
        ("phase", html.escape(str(snap.phase))),
    ]
    if outcome:
        items.append(("outcome", f'<b style="color:{out_col}">{html.escape(outcome)}</b>'))
    items += _timing_items(snap.timing, rate_hz, jitter_max_ms)
    if viewer:
        items += [(k, html.escape(str(v))) for k, v in viewer.items()]
    cells = " ".join(
        f'<span class="dst-item"><span class="dst-key">{k}</span> {v}</span>' for k, v in items
    )
    return (
        f'<div class="dst-status" data-status="{html.escape(status)}" '
        f'data-mode="{html.escape(str(snap.mode))}" data-phase="{html.escape(str(snap.phase))}" '
        f'data-outcome="{html.escape(outcome)}" data-tick="{int(snap.tick)}" '
        f'data-rate-hz="{"" if rate_hz is None else f"{rate_hz:.2f}"}" '
        ">"
        f'<div style="font-size:14px"><span style="display:inline-block;width:10px;height:10px;'
        f'border-radius:5px;background:{colour};margin-right:6px"></span>'
        f"<b>{html.escape(status)}</b>{reason}</div>{cells}</div>"
    )


class AlphaHistory:
    """A fixed window of alpha samples for the time-series plot.

    Args:
        dims: dimension names (one series each).
        length: samples kept.
    """

    def __init__(self, dims: Sequence[str], length: int) -> None:
        self.dims = tuple(dims)
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
        """(t, alpha_0, ..., alpha_D-1) over the filled part of the window, t from 0 at the
        oldest sample shown."""
        k = min(self._n, self._t.size)
        t = self._t[-k:] - (self._t[-k] if k else 0.0)
        return (t, *(row[-k:] for row in self._a))


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
    pts = np.round(np.asarray(landmarks)[:, :2] * (w, h)).astype(int)
    if not np.isfinite(landmarks[:, :2]).all():
        return
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


def camera_image(hand: Any, width_px: int = CAMERA_WIDTH_PX) -> Image | None:
    """A small RGB image of the tracked hand: the camera frame (or a grey canvas for
    sources without pixels) downscaled to `width_px`, with the landmarks drawn.

    `hand` is the snapshot's `hand` field: an object with `image` (BGR) and `sample`
    (with `landmarks_image`, `detected`, `width_px`, `height_px`), or a tracked sample itself.
    Returns None when there is nothing to show.
    """
    if hand is None:
        return None
    sample = getattr(hand, "sample", None) or hand
    image = getattr(hand, "image", None)
    landmarks = getattr(sample, "landmarks_image", None)
    detected = bool(getattr(sample, "detected", landmarks is not None))
    if image is None and landmarks is None:
        return None
    cv2: Any = importlib.import_module("cv2")
    if image is not None:
        src = np.asarray(image)
        scale = width_px / src.shape[1]
        small = cv2.resize(
            src, (width_px, max(1, round(src.shape[0] * scale))), interpolation=cv2.INTER_AREA
        )
        canvas: Image = np.ascontiguousarray(small[:, :, ::-1])  # BGR -> RGB
    else:
        w = int(getattr(sample, "width_px", 640) or 640)
        h = int(getattr(sample, "height_px", 480) or 480)
        canvas = np.full((max(1, round(h * width_px / w)), width_px, 3), 60, dtype=np.uint8)
    if detected and landmarks is not None:
        _draw_landmarks(canvas, np.asarray(landmarks, dtype=np.float64))
    return canvas
