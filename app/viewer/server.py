"""The browser view: a Viser server fed by the loop's snapshots, a sink with a mailbox back.

The viewer is a sink (docs/viewer.md, "How it is built"). It owns a `viser.ViserServer` and
one thread that reads its own one-slot `Subscription` of the loop's `Broadcaster`: the loop
only ever overwrites that slot, so a slow viewer, or a closed or stalled browser tab behind
it, skips snapshots and never slows the loop. Viser's per-client message buffer then keeps only the
newest update per element, so a slow client coalesces as well. GUI callbacks only post
requests to `Controls`, which the loop takes once per tick; the viewer never touches the
loop's state and never imports PyBullet.

Rates (configurable, `ViewerConfig`):

    scene     <= 30 Hz   bodies, ghost hand, goal frames; one `server.atomic()` per update
    panel     ~10 Hz     per-dimension gauges, status, the alpha plot, the trail
    camera    ~5 Hz      downscaled camera image with the landmarks drawn

Several tabs see the same session: every element is added to the server (shared) scene and
GUI, so all clients get the same state, and a new tab is brought up to date by viser.

The operator's stop: a red "Stop robot" button at the top of the controls (and the Escape
key) posts `Controls.stop_robot`; the loop latches it and halts the robot as for a lost hand
until "Resume" (or Shift+R) posts `Controls.resume_robot`. Resume is enabled only while the
records say the stop is latched; a banner under the buttons and the status line say
"stopped". The keys are viser commands (also listed in its command palette, Ctrl+K); like
every viser hotkey they do not fire while the cursor is in a text or number box.

Layout (fits a 1366 x 768 window without scrolling to reach a control): the controls and the
live parameters in a panel docked on the left (a "Hand -> robot" tab beside them says what
each hand motion does); on the right the status line (with the source), the tally of trials,
the gauges and their legend, the alpha plot and the camera. A parameter is checked at the
widget before it is posted: outside its slider's range, or refused by `ArbitrationConfig`'s
own validation, it is not sent, and the panel says why and which value the loop keeps.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import html
import io
import logging
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np

if TYPE_CHECKING:
    import viser

from dsteleop.app.loop.broadcast import Broadcaster, Subscription
from dsteleop.app.loop.controls import Controls
from dsteleop.app.session.schema import TickRecord
from dsteleop.app.viewer.panel import (
    DEMO_NOTE,
    MODE_HINT,
    PLOT_AXES,
    PLOT_CAPTION,
    PLOT_LEGEND,
    RESUME_KEY,
    STOP_KEY,
    AlphaHistory,
    TrialTally,
    belief_html,
    camera_image,
    gauges_html,
    legend_html,
    mapping_html,
    plot_series,
    status_html,
    stop_html,
    style_html,
    tally_html,
)
from dsteleop.app.viewer.scene import SceneView
from dsteleop.arbitration import ArbitrationConfig, ArbitrationStep, HandState, registered
from dsteleop.errors import ConfigError, DsteleopError, InputError
from dsteleop.robot.scene import SceneGeometry
from dsteleop.tracking.mapping import MappingConfig

log = logging.getLogger(__name__)


def mode_names() -> tuple[str, ...]:
    """The modes the dropdown offers: every registered one (`arbitration.modes`)."""
    return tuple(m.value for m in registered())


DEFAULT_UTENSILS: tuple[str, ...] = ("spoon", "spatula", "ladle")


@dataclass(frozen=True)
class Slider:
    """A live hyper-parameter slider: the name is the key posted to `Controls.set_params`."""

    name: str
    label: str
    low: float
    high: float
    step: float
    initial: float
    integer: bool = False


# The main hyper-parameters (docs/METHOD.md §6; ArbitrationConfig's defaults).
DEFAULT_SLIDERS: tuple[Slider, ...] = (
    Slider("kappa", "kappa (von Mises)", 0.5, 20.0, 0.5, 4.0),
    Slider("p", "p (beta prime)", 1.5, 20.0, 0.5, 4.0),  # > 1: eq (7) needs a mode
    Slider("q", "q (beta prime)", 1.5, 20.0, 0.5, 6.0),
    Slider("b", "b (willingness scale)", 0.1, 3.0, 0.05, 1.0),
    Slider("window", "window [ticks]", 1, 30, 1, 5, integer=True),
    Slider("goal_noise_m", "goal noise [m]", 0.0, 0.05, 0.001, 0.0),
)


def sliders_for(arbitration: ArbitrationConfig, goal_noise_m: float) -> tuple[Slider, ...]:
    """The GUI sliders, starting at the loop's current values (clipped to their ranges)."""
    now = {**arbitration.to_dict(), "goal_noise_m": goal_noise_m}
    return tuple(
        dataclasses.replace(s, initial=min(max(float(now.get(s.name, s.initial)), s.low), s.high))
        for s in DEFAULT_SLIDERS
    )


def refusal(slider: Slider, value: float, arbitration: ArbitrationConfig) -> str | None:
    """Why the GUI refuses this value of this slider, or None when the loop may take it.

    A value outside the slider's range, or one that `ArbitrationConfig` itself refuses (its
    validation, not a copy of it), is refused; non-arbitration sliders (`goal_noise_m`) are
    checked against their range only.
    """
    v = float(value)
    if not math.isfinite(v) or not (slider.low <= v <= slider.high):
        return f"{slider.name} must be in [{slider.low:g}, {slider.high:g}], got {v:g}"
    if slider.integer and v != round(v):
        return f"{slider.name} must be a whole number, got {v:g}"
    if slider.name not in ArbitrationConfig.field_names():
        return None
    try:
        arbitration.replace(**{slider.name: round(v) if slider.integer else v})
    except DsteleopError as exc:
        return str(exc)
    return None


@dataclass(frozen=True)
class ViewerConfig:
    """Where the view listens and how often it updates.

    Attributes:
        host: address to listen on (127.0.0.1: this machine only).
        port: TCP port; 0 picks a free one.
        scene_hz: maximum scene update rate [Hz].
        panel_hz: gauges / status / trail update rate [Hz] (the plot samples at this rate).
        plot_hz: rate at which the alpha plot is re-sent [Hz].
        camera_hz: camera image update rate [Hz]; 0 disables the image.
        plot_window_s: time span of the alpha plot [s].
        trail_points: positions kept in the output trajectory's trail.
        title: label at the top of the GUI panel.
    """

    host: str = "127.0.0.1"
    port: int = 8080
    scene_hz: float = 30.0
    panel_hz: float = 10.0
    plot_hz: float = 5.0
    camera_hz: float = 5.0
    plot_window_s: float = 10.0
    trail_points: int = 150
    title: str = "dsteleop"

    def __post_init__(self) -> None:
        if not (0 <= self.port <= 65535):
            raise ConfigError(f"viewer: port must be in 0..65535, got {self.port}")
        for name in ("scene_hz", "panel_hz", "plot_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 < v <= 120):
                raise ConfigError(f"viewer: {name} must be in (0, 120], got {v}")
        if not (math.isfinite(self.camera_hz) and 0 <= self.camera_hz <= 30):
            raise ConfigError(f"viewer: camera_hz must be in [0, 30], got {self.camera_hz}")


@dataclass
class ViewerStats:
    """Counters of the viewer thread (read from any thread; approximate)."""

    scene_updates: int = 0
    panel_updates: int = 0
    camera_updates: int = 0
    errors: int = 0
    update_ms: list[float] = field(default_factory=list)


def check_port_free(host: str, port: int) -> None:
    """Fail with one clear line when `host:port` cannot be listened on.

    Viser would silently move to the next free port; an operator who typed a port must get
    that port or an error.

    Raises:
        InputError: the port is in use, or the host is not an address of this machine.
    """
    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise InputError(f"cannot listen on {host}:{port}: unknown host ({exc})") from exc
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server does
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise InputError(
                    f"port {port} is already in use on {host} (stop the other program or "
                    "choose another with --port)"
                ) from exc
            raise InputError(f"cannot listen on {host}:{port}: {exc.strerror}") from exc


class Viewer:
    """The browser view of one live session.

    Args:
        broadcaster: the loop's snapshot broadcaster (the viewer subscribes on `start`).
        controls: the loop's request mailbox (GUI callbacks post here, nothing else).
        scene: the plant's scene description, or None to draw the robot hand as a proxy at
            the achieved pose.
        config: listen address and update rates.
        utensils: what the Utensil menu offers: "infer" (the robot is told no utensil) and
            the utensils (a utensil tells the robot that one).
        utensil: the menu's value at start (the task's goal), default its first.
        sliders: hyper-parameter sliders (initial values should match the loop's config).
        arbitration: the loop's arbitration config: parameter changes are checked against
            it before they are posted (`refusal`).
        source: what drives the hand, for the status line (`panel.source_label`).
        mapping: the hand's workspace mapping, for the "Hand -> robot" help (None: none).
        info: fixed facts shown in the status line (name -> text), e.g. impairments.

    Raises:
        InputError: when the port is in use or the host cannot be listened on.
    """

    def __init__(
        self,
        broadcaster: Broadcaster,
        controls: Controls,
        scene: SceneGeometry | None = None,
        config: ViewerConfig | None = None,
        utensils: Sequence[str] = DEFAULT_UTENSILS,
        sliders: Sequence[Slider] = DEFAULT_SLIDERS,
        arbitration: ArbitrationConfig | None = None,
        source: str = "",
        mapping: MappingConfig | None = None,
        info: Mapping[str, str] | None = None,
        utensil: str | None = None,
    ) -> None:
        import viser  # heavy: imported only when a view is built

        self.config = cfg = config or ViewerConfig()
        self._broadcaster = broadcaster
        self._controls = controls
        self._geometry = scene
        check_port_free(cfg.host, cfg.port)
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner; we log
            self.server = viser.ViserServer(
                host=cfg.host, port=cfg.port, label=cfg.title, verbose=False
            )
        if cfg.port != 0 and self.server.get_port() != cfg.port:  # lost a race for the port
            self._stop_server()
            raise InputError(f"port {cfg.port} is already in use on {cfg.host}")
        log.info("viewer listening on %s:%d", cfg.host, self.port)
        self.stats = ViewerStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sub: Subscription | None = None
        self._last_step: ArbitrationStep | None = None
        self._last_hand: HandState | None = None
        self._dims: tuple[str, ...] = ()
        self._history: AlphaHistory | None = None
        self._plot: viser.GuiUplotHandle | None = None
        self._image: viser.GuiImageHandle | None = None
        self._camera_seq: int | None = None
        self._t_plot = -math.inf
        self._recent: tuple[float | None, float | None] = (None, None)
        self._rate_marks: deque[tuple[int, float, float]] = deque(maxlen=64)
        self.source = source
        self.info = dict(info or {})
        self.tally = TrialTally()
        self._arbitration = arbitration or ArbitrationConfig()
        self._accepted: dict[str, float] = {}
        self.refused: dict[str, str] = {}  # slider name -> why its last value was refused
        self._mapping = mapping
        self._utensil_at_start = utensil
        self._build(utensils, sliders)

    # ------------------------------------------------------------------ public
    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        """The address to open in a browser (127.0.0.1 when listening on all interfaces)."""
        host = self.config.host
        if host in ("0.0.0.0", "::", ""):
            host = "127.0.0.1"
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{self.port}/"

    @property
    def clients(self) -> int:
        """Number of connected browser tabs (0 once closed)."""
        server = self.server
        return 0 if server is None else len(server.get_clients())

    def start(self) -> None:
        """Subscribe to the loop and start the viewer thread."""
        if self._thread is not None:
            return
        self._sub = self._broadcaster.subscribe()
        self._thread = threading.Thread(target=self._run, name="dsteleop-viewer", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread, unsubscribe and stop the server (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._sub is not None:
            self._sub.close()
            self._sub = None
        self._stop_server()

    def _stop_server(self) -> None:
        server, self.server = self.server, None  # type: ignore[assignment]
        if server is not None:
            with contextlib.redirect_stdout(io.StringIO()):  # "(viser) Server stopped"
                server.stop()

    def __enter__(self) -> Viewer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ GUI
    def _build(self, utensils: Sequence[str], sliders: Sequence[Slider]) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large", dark_mode=False, show_logo=False)
        # from behind the base's left, looking at the table where the scene stands
        fx, fy, fz = (self._geometry or SceneGeometry).focus_m  # the class's: its default
        self.server.initial_camera.position = (fx - 1.3, fy - 1.25, fz + 0.9)
        self.server.initial_camera.look_at = (fx, fy, fz)
        self.scene = SceneView(self.server.scene, self._geometry, self.config.trail_points)

        gui.add_html(style_html())
        self._status = gui.add_html(
            f'<div class="dst-status" data-source="{html.escape(self.source)}" '
            'data-status="waiting">waiting for the loop&hellip;</div>'
        )
        self._tally = gui.add_html(tally_html(self.tally))
        self._belief = gui.add_html(belief_html(None))
        self._gauges = gui.add_html('<div class="dst-gauges" data-tick="-1"></div>')
        gui.add_html(legend_html())
        self._plot_folder = gui.add_folder("Authority over time (alpha)")
        with self._plot_folder:
            gui.add_html(f'<div class="dst-note">{html.escape(PLOT_CAPTION)}</div>')
        self._camera_folder = gui.add_folder("Camera")
        with self._camera_folder:
            demo = self.source == "demo"
            note = f"demo: {DEMO_NOTE}; the grey canvas shows its simulated hand" if demo else ""
            self._camera_caption = gui.add_html(f'<div class="dst-note">{note}</div>')
            self._camera_note = gui.add_html('<div class="dst-note">no camera image</div>')

        side = gui.add_panel()
        with side.add_tab("Controls"):
            self._add_controls(utensils, sliders)
        with side.add_tab("Hand → robot"):
            gui.add_html(mapping_html(self._mapping))
        side.dock_left()
        side.set_width(320)
        self._side = side
        main = gui.main_panel
        main.dock_right()  # the scene between the two panels, none of it under them
        main.set_width(415)

    def _add_controls(self, utensils: Sequence[str], sliders: Sequence[Slider]) -> None:
        gui = self.server.gui
        self._add_stop()
        names = mode_names()
        mode = gui.add_dropdown("Mode", names, initial_value=names[0], hint=MODE_HINT)
        self._mode = mode
        self._mode_followed = names[0]  # the loop's mode the dropdown last followed

        @mode.on_update
        def _(event: viser.GuiEvent[viser.GuiDropdownHandle[str]]) -> None:
            if event.client is not None:  # a person chose it (not our own sync)
                self._controls.set_mode(str(mode.value))

        buttons = gui.add_button_group("Hand / task", ("Calibrate", "Reset task"))

        @buttons.on_click
        def _(event: viser.GuiEvent[viser.GuiButtonGroupHandle]) -> None:
            if event.target.value == "Calibrate":
                self._controls.calibrate()
            else:
                self._controls.reset(str(utensil.value))

        names = tuple(utensils) or DEFAULT_UTENSILS
        first = self._utensil_at_start if self._utensil_at_start in names else names[0]
        utensil = gui.add_dropdown(
            "Utensil",
            names,
            initial_value=first,
            hint="the robot's goal at the next reset: a utensil (told), or infer (told none: it "
            "infers the person's from the hand's motion)",
        )

        @utensil.on_update
        def _(event: viser.GuiEvent[viser.GuiDropdownHandle[str]]) -> None:
            if event.client is not None:
                self._controls.choose_utensil(str(utensil.value))

        record = gui.add_button_group("Recording", ("Start", "Stop"))

        @record.on_click
        def _(event: viser.GuiEvent[viser.GuiButtonGroupHandle]) -> None:
            self._controls.set_recording(event.target.value == "Start")

        with gui.add_folder("Parameters (live, recorded)", expand_by_default=True):
            for s in sliders:
                self._add_slider(s)
            self._refused_note = gui.add_html('<div class="dst-refused" data-refused=""></div>')

    def _add_stop(self) -> None:
        """The Stop and Resume buttons, their keys and the stop banner (module docstring)."""
        import viser

        gui = self.server.gui
        stop = gui.add_button(
            "Stop robot", color="red", icon=viser.Icon.HAND_STOP, hint=f"halt it ({STOP_KEY})"
        )
        resume = gui.add_button(
            "Resume", color="green", icon=viser.Icon.PLAYER_PLAY, disabled=True, hint=RESUME_KEY
        )
        self._resume = resume
        self._stop_note = gui.add_html(stop_html(False))
        self._shown_stopped = False
        stop_key = gui.add_command(
            "Stop the robot", description="halts it until Resume", hotkey="escape"
        )
        resume_key = gui.add_command(
            "Resume the robot", description="after a stop", hotkey="R", modifier="shift"
        )

        @stop.on_click
        def _(event: viser.GuiEvent[viser.GuiButtonHandle]) -> None:
            self._controls.stop_robot()

        @stop_key.on_trigger
        def _(event: viser.CommandEvent) -> None:
            self._controls.stop_robot()

        @resume.on_click
        def _(event: viser.GuiEvent[viser.GuiButtonHandle]) -> None:
            self._controls.resume_robot()

        @resume_key.on_trigger
        def _(event: viser.CommandEvent) -> None:
            self._controls.resume_robot()

    def _show_stopped(self, stopped: bool) -> None:
        """The buttons and the banner as the loop's records say (only when it changed)."""
        if stopped == self._shown_stopped:
            return
        self._shown_stopped = stopped
        self._resume.disabled = not stopped
        self._stop_note.content = stop_html(stopped)

    def _add_slider(self, s: Slider) -> None:
        handle = self.server.gui.add_slider(
            s.label,
            min=s.low,
            max=s.high,
            step=s.step,
            initial_value=s.initial,
            hint=f"{s.name}: {s.low:g} to {s.high:g}",
        )
        self._accepted[s.name] = s.initial

        @handle.on_update
        def _(event: viser.GuiEvent[viser.GuiSliderHandle[float]]) -> None:
            if event.client is not None:
                self.offer_param(s, handle.value)

    def offer_param(self, slider: Slider, value: float) -> bool:
        """A value a person set on a slider: posted to the loop if valid (True), else refused
        with the reason shown under the sliders (the loop keeps its value)."""
        why = refusal(slider, value, self._arbitration)
        if why is None:
            v = round(value) if slider.integer else float(value)
            if slider.name in ArbitrationConfig.field_names():
                self._arbitration = self._arbitration.replace(**{slider.name: v})
            self._accepted[slider.name] = float(v)
            self.refused.pop(slider.name, None)
            self._controls.set_params(**{slider.name: v})
        else:
            self.refused[slider.name] = why
        self._show_refusals()
        return why is None

    def _show_refusals(self) -> None:
        lines = "".join(
            f"<div>{html.escape(name)} not applied: {html.escape(why)} "
            f"(the loop keeps {self._accepted[name]:g})</div>"
            for name, why in self.refused.items()
        )
        names = html.escape(",".join(self.refused))
        self._refused_note.content = (
            f'<div class="dst-refused" data-refused="{names}">{lines}</div>'
        )

    def _ensure_plot(self, dims: tuple[str, ...]) -> None:
        if dims == self._dims:
            return
        self._dims = dims
        n = max(2, round(self.config.plot_window_s * self.config.panel_hz))
        self._history = AlphaHistory(dims, n, self.config.plot_window_s)
        if self._plot is not None:
            self._plot.remove()
        with self._plot_folder:
            self._plot = self.server.gui.add_uplot(
                data=(np.zeros(2), *(np.zeros(2) for _ in dims)),
                series=plot_series(dims),  # type: ignore[arg-type]
                scales=cast(Any, {"x": {"time": False, "auto": True}, "y": {"range": [0, 1]}}),
                axes=cast(Any, PLOT_AXES),
                legend=cast(Any, PLOT_LEGEND),
                height=180,
            )

    # ------------------------------------------------------------------ thread
    def _run(self) -> None:
        cfg = self.config
        scene_dt = 1.0 / cfg.scene_hz
        panel_dt = 1.0 / cfg.panel_hz
        camera_dt = 1.0 / cfg.camera_hz if cfg.camera_hz > 0 else math.inf
        t_scene = t_panel = t_camera = -math.inf
        while not self._stop.is_set():
            snap = self._sub.wait(0.2) if self._sub is not None else None
            if snap is None:
                continue
            now = time.monotonic()
            if now - t_scene < scene_dt:  # never faster than scene_hz; the slot coalesces
                self._stop.wait(scene_dt - (now - t_scene))
                latest = self._sub.latest() if self._sub is not None else None
                snap = latest or snap
                now = time.monotonic()
            try:
                t0 = time.perf_counter()
                if snap.step is not None:
                    self._last_step = snap.step
                if snap.X_human is not None:
                    self._last_hand = snap.X_human
                with self.server.atomic():
                    self.scene.update(snap, self._last_hand)
                self._recent = self.recent_timing(snap)
                t_scene = now
                self.stats.scene_updates += 1
                if now - t_panel >= panel_dt:
                    t_panel = now
                    self._update_panel(snap)
                if now - t_camera >= camera_dt:
                    t_camera = now
                    self._update_camera(snap)
                ms = (time.perf_counter() - t0) * 1e3
                if len(self.stats.update_ms) < 100_000:
                    self.stats.update_ms.append(ms)
            except Exception:  # the view must never take the session down
                self.stats.errors += 1
                if self.stats.errors <= 3:
                    log.exception("viewer: update failed (tick %s)", snap.k)
                if self._stop.is_set() or self.server is None:
                    return

    def recent_timing(self, snap: TickRecord) -> tuple[float | None, float | None]:
        """The loop's rate (ticks per loop second) and largest start-time jitter [ms] over
        the last ~second of records this view saw."""
        marks = self._rate_marks
        if marks and snap.k < marks[-1][0]:
            marks.clear()  # the task was reset: ticks restart from 0
        marks.append((int(snap.k), float(snap.t_s), float(snap.timing.get("jitter_ms", 0.0))))
        while len(marks) > 2 and marks[-1][1] - marks[0][1] > 1.0:
            marks.popleft()
        (k0, t0, _), (k1, t1, _) = marks[0], marks[-1]
        rate = (k1 - k0) / (t1 - t0) if t1 - t0 > 0.2 else None
        return rate, max(m[2] for m in marks)

    def viewer_counters(self) -> Mapping[str, Any]:
        """What the status line shows about the view itself."""
        sub = self._sub
        return {
            "tabs": self.clients,
            "view skipped": sub.dropped if sub is not None else 0,
        }

    def _update_panel(self, snap: TickRecord) -> None:
        dims = tuple(snap.dims)
        self._ensure_plot(dims)
        assert self._history is not None
        D = len(snap.dims)
        shown = self._last_step
        self._history.push(float(snap.t_s), np.zeros(D) if shown is None else shown.alpha)
        timing = self._recent
        with self.server.atomic():
            self.scene.trail.draw()
            self._status.content = status_html(
                snap, self.viewer_counters(), *timing, source=self.source, info=self.info
            )
            if self.tally.observe(snap) is not None:
                self._tally.content = tally_html(self.tally)
            self._gauges.content = gauges_html(snap, self._last_step)
            self._belief.content = belief_html(snap)
            self._show_stopped(snap.stopped)
            now = time.monotonic()
            if self._plot is not None and now - self._t_plot >= 1.0 / self.config.plot_hz:
                self._t_plot = now
                self._plot.data = self._history.data()
            self._follow_mode(snap.mode.value)
        self.stats.panel_updates += 1

    def _follow_mode(self, mode: str) -> None:
        """The dropdown follows the loop's changes of mode (posted by no one). Only changes:
        a mode a person just chose differs from the loop's until the loop takes it, and
        setting the dropdown back meanwhile would make the person's own callback (which
        reads the dropdown's value in viser's thread pool) post the old mode instead."""
        if mode == self._mode_followed or mode not in mode_names():
            return
        self._mode_followed = mode
        if self._mode.value != mode:
            # viser types a dropdown's value read-only (its props class declares the field);
            # the handle's setter is what runs
            self._mode.value = mode  # type: ignore[misc]

    def _update_camera(self, snap: TickRecord) -> None:
        seq = None if snap.hand is None else snap.hand.seq
        if seq is not None and seq == self._camera_seq:
            return  # the same frame as last time (a source that ended or stalled)
        self._camera_seq = seq
        img = camera_image(snap.hand)
        if img is None:
            return
        if self._image is None:
            self._camera_note.visible = False
            with self._camera_folder:
                self._image = self.server.gui.add_image(img, format="jpeg", jpeg_quality=70)
        else:
            self._image.image = img
        self.stats.camera_updates += 1
