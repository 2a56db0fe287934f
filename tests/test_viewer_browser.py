"""The browser view in a real browser: `dsteleop serve` and headless Chromium.

Everything is checked from the page itself (the DOM Viser renders, and the WebGL canvas):
the gauges are present and their values change, the scene is drawn, a mode chosen in the
page reaches the loop, two tabs see the same session while the loop keeps its rate, and with
a video source the camera panel shows the video's pixels (not the grey canvas). The
operator's stop (issue 33, item 9): the page's Stop button, and the Escape key, halt the
robot until Resume (or Shift+R). What the page says it shows (issue 23, item 5): the source
in the status line, the tally of trials after a success, the legend's wording; at 1366 x
768 every control is on screen, and a value typed into a parameter's box that the loop
would refuse is refused there, with the reason.
Uses Debian's system Chromium (`/usr/bin/chromium`, installed by .ci/run); without it the
tests skip with the reason. WebGL runs in software there, so waits are generous but
bounded: a wait ends when what it waits for happens, at the latest after tests/deadlines.py's
HUNG_S.
A screenshot is saved under test-artifacts/; `DSTELEOP_UPDATE_SCREENSHOT=1` also copies it to
docs/screenshot.png (the README's).
"""

from __future__ import annotations

import base64
import contextlib
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from tests.deadlines import HUNG_S, held_rate_floor

if TYPE_CHECKING:
    from playwright.sync_api import Browser, Page

from dsteleop.app.viewer.panel import MODE_HINT

REPO = Path(__file__).resolve().parents[1]
ARTIFACTS = REPO / "test-artifacts"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]
DIMS = ["x", "y", "z", "roll", "pitch", "yaw", "thumb", "index", "middle", "ring"]
PAGE_TIMEOUT_MS = 90_000  # software WebGL on two shared cores: slow, but bounded
SMALL_WINDOW = (1366, 768)  # a common laptop screen: the controls must fit it

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason=f"{CHROMIUM} not found (apt-get install chromium; .ci/run installs it)",
    ),
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def _serve(*args: str) -> Iterator[str]:
    """`dsteleop serve ARGS --port <free>` until the block ends (then Ctrl-C); its URL."""
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "dsteleop.app.cli.main", "serve", *args, "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    url = f"http://127.0.0.1:{port}/"
    try:
        assert proc.stderr is not None
        deadline = time.monotonic() + 60.0
        seen = []
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            seen.append(line)
            if url in line or not line:
                break
        assert any(url in ln for ln in seen), "".join(seen)
        yield url
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise
    assert proc.returncode == 0, err[-2000:]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("recordings")


@pytest.fixture(scope="module")
def served(recordings: Path) -> Iterator[str]:
    """`dsteleop serve --source demo --record DIR` on a free local port; its URL. Stopped
    with Ctrl-C."""
    with _serve("--source", "demo", "--record", str(recordings)) as url:
        yield url


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


def _open(browser: Browser, url: str, width: int = 1400, height: int = 900) -> Page:
    page = browser.new_page(viewport={"width": width, "height": height})
    page.set_default_timeout(PAGE_TIMEOUT_MS)
    page.goto(url)
    page.wait_for_function(
        "n => document.querySelectorAll('.dst-gauge').length === n", arg=len(DIMS)
    )
    return page


def _gauges(page: Page) -> dict[str, dict[str, float]]:
    rows = page.eval_on_selector_all(".dst-gauge", "els => els.map(e => ({...e.dataset}))")
    return {r["dim"]: {k: float(r[k]) for k in ("alpha", "ph", "pr", "b")} for r in rows}


def _status(page: Page) -> dict[str, str]:
    return dict(page.eval_on_selector(".dst-status", "e => ({...e.dataset})"))


def _scene_drawn(page: Page) -> bool:
    """The WebGL canvas shows the robot: enough of the arm's orange and blue pixels."""
    import cv2

    png = page.locator("canvas").first.screenshot()
    decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert decoded is not None
    img = decoded.astype(int)
    b, g, r = img[..., 0], img[..., 1], img[..., 2]
    orange = (r > 180) & (g > 60) & (g < 160) & (b < 90)
    blue = (b > 170) & (r < 150)
    return bool(orange.sum() > 500 and blue.sum() > 500)


def _wait(pred: Callable[[], bool], timeout_s: float, what: str, page: Page) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return
        page.wait_for_timeout(500)
    raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")


def test_page_shows_the_scene_and_live_gauges(served: str, browser: Browser) -> None:
    page = _open(browser, served, *SMALL_WINDOW)
    try:
        _wait(lambda: _scene_drawn(page), 90.0, "the arm in the 3-D view", page)
        first = _gauges(page)
        assert list(first) == DIMS
        for values in first.values():
            assert all(0.0 <= v <= 1.0 for v in values.values()), values
        # The demo operator moves: some value of some gauge changes within seconds.
        _wait(lambda: _gauges(page) != first, HUNG_S, "the gauges to change", page)
        status = _status(page)
        assert status["mode"] == "DS" and status["status"] in (
            "tracking",
            "lost",
            "assist",
            "finished",
        )
        ticks = int(status["tick"])
        _wait(lambda: int(_status(page)["tick"]) != ticks, HUNG_S, "the loop to tick", page)
        # Dismiss viser's "software WebGL" notice, then keep a screenshot.
        close = page.locator(".mantine-Notification-closeButton")
        if close.count():
            close.first.click()
        _wait(lambda: _status(page)["status"] == "tracking", HUNG_S, "a tracked hand", page)
        page.wait_for_timeout(1500)
        ARTIFACTS.mkdir(exist_ok=True)
        shot = ARTIFACTS / "viewer.png"
        page.screenshot(path=str(shot))
        assert shot.stat().st_size > 20_000
        # The README's screenshot: written when absent, or on request, so that a test run
        # does not rewrite a tracked file.
        doc = REPO / "docs" / "screenshot.png"
        if not doc.exists() or os.environ.get("DSTELEOP_UPDATE_SCREENSHOT") == "1":
            shutil.copyfile(shot, doc)
    finally:
        page.close()


def test_controls_in_the_page_reach_the_loop(served: str, browser: Browser) -> None:
    page = _open(browser, served)
    try:
        mode = page.get_by_role("combobox").first
        assert mode.input_value() == "DS"
        mode.click()
        page.get_by_role("option", name="manual", exact=True).click()
        _wait(lambda: _status(page)["mode"] == "manual", HUNG_S, "the loop in manual mode", page)
        # Manual gives the operator everything on every dimension, once arbitrating.
        _wait(
            lambda: (
                _status(page)["status"] != "tracking"
                or all(v["alpha"] == 0.0 for v in _gauges(page).values())
            ),
            HUNG_S,
            "alpha = 0 everywhere",
            page,
        )
        mode.click()
        page.get_by_role("option", name="DS", exact=True).click()
        _wait(lambda: _status(page)["mode"] == "DS", HUNG_S, "the loop back in DS", page)
        # Reset task: the loop restarts the task, its tick count starts again from 0.
        _wait(lambda: int(_status(page)["tick"]) > 90, HUNG_S, "three seconds of ticks", page)
        before = int(_status(page)["tick"])
        page.get_by_role("button", name="Reset task").click()
        _wait(lambda: int(_status(page)["tick"]) < before, HUNG_S, "the task to restart", page)
    finally:
        page.close()


_STATUS_JS = """e => ({
    ...e.dataset,
    line: e.querySelector('.dst-status-line').innerText,
    colour: e.querySelector('.dst-status-line b').style.color,
})"""


def test_status_after_a_success_and_the_recording_indicator(
    served: str, browser: Browser, recordings: Path
) -> None:
    """After the demo's success the status says finished, with the outcome, in green (never
    "lost"); the recording running since the start shows its time and episodes; the gauges'
    marks are explained on the page."""
    page = _open(browser, served)
    try:
        legend = page.locator(".dst-legend").inner_text()
        assert all(w in legend for w in ("P(H)", "P(R)", "B", "robot", "operator")), legend
        # ... as eq (4)-(8) define them, not as probabilities of who is in control.
        for words in ("operator's own pose would imply", "the same for the robot's pose",
                      "willingness (eq 7)", "(eq 8)"):  # fmt: skip
            assert words in legend, (words, legend)
        assert "how likely" not in legend, legend
        # The source: the demo, said to be no camera.
        status = page.locator(".dst-status")
        assert status.get_attribute("data-source") == "demo"
        assert "synthetic operator, no camera" in status.inner_text()
        rec = page.locator(".dst-rec")
        rec.wait_for(state="attached")
        data = rec.evaluate("e => ({...e.dataset})")
        assert Path(data["recording"]).parent == recordings, data
        assert "REC" in rec.inner_text()
        # The demo (DS, seed 0) succeeds; the task restarts 4 s after each outcome, so the
        # status, its words and its colour are read in one go.
        seen: list[dict[str, str]] = []

        def finished() -> bool:
            snap = page.eval_on_selector(".dst-status", _STATUS_JS)
            seen.append(snap)
            return bool(snap["status"] == "finished" and snap["outcome"] == "success")

        _wait(finished, 150.0, "the status after a success", page)
        snap = seen[-1]
        line = snap["line"]
        assert line.startswith("finished") and "success" in line and "lost" not in line, line
        assert snap["colour"] == "rgb(31, 157, 85)", snap  # green
        # The tally has the trial: a success, its time from the trial's start.
        tally = page.locator(".dst-tally")
        _wait(
            lambda: int(tally.get_attribute("data-successes") or 0) >= 1,
            HUNG_S,
            "the success in the tally",
            page,
        )
        newest = page.locator(".dst-trial").first.evaluate("e => ({...e.dataset})")
        assert newest["outcome"] == "success" and newest["mode"] == "DS", newest
        assert 1.0 < float(newest["timeS"]) < 120.0, newest
        assert "success" in tally.inner_text() and "Trials since start" in tally.inner_text()
        _wait(
            lambda: int(rec.evaluate("e => e.dataset.episodes")) >= 1,
            HUNG_S,
            "the episode counted in the indicator",
            page,
        )
        assert float(rec.evaluate("e => e.dataset.elapsedS")) > 5.0
    finally:
        page.close()


def _on_screen(page: Page, locator: Any) -> bool:
    box = locator.bounding_box()
    w, h = SMALL_WINDOW
    return bool(box and box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= w
                and box["y"] + box["height"] <= h)  # fmt: skip


def test_controls_fit_a_laptop_window_and_bad_values_are_refused_with_the_reason(
    served: str, browser: Browser
) -> None:
    """At 1366 x 768 every control is on screen without scrolling; the plot's legend names
    the lines (no "--"); the mapping help is one click away; a value typed into a
    parameter's box that the loop would refuse is refused at the widget, the reason shown."""
    page = _open(browser, served, *SMALL_WINDOW)
    try:
        boxes = page.locator("input.mantine-NumberInput-input")
        controls = {
            "mode": page.get_by_role("combobox").first,
            "stop": page.get_by_role("button", name="Stop robot"),
            "reset": page.get_by_role("button", name="Reset task"),
            "record": page.get_by_role("button", name="Start", exact=True),
            "first parameter": boxes.first,
            "last parameter": boxes.last,
        }
        assert boxes.count() == 6
        for name, control in controls.items():
            assert _on_screen(page, control), (name, control.bounding_box())
        assert page.evaluate("window.scrollY") == 0
        # Why DS is the default: the Mode control's hint, a tooltip over the page while the
        # pointer is on the control, on screen and taking no room from the controls.
        controls["mode"].hover()
        hint = page.get_by_role("tooltip").filter(has_text="DS is the default")
        hint.wait_for(state="visible")
        assert hint.inner_text().strip() == MODE_HINT
        assert _on_screen(page, hint), hint.bounding_box()
        page.mouse.move(700, 400)
        for name, control in controls.items():
            assert _on_screen(page, control), (name, control.bounding_box())
        legend = page.locator(".u-legend").first
        legend.wait_for(state="attached")
        text = legend.inner_text()
        assert all(d in text for d in DIMS) and "--" not in text, text
        page.get_by_role("tab", name="Hand → robot").click()
        help_text = page.locator(".dst-mapping").inner_text()
        assert "towards the camera" in help_text and "robot +x" in help_text, help_text
        page.get_by_role("tab", name="Controls").click()
        kappa = page.locator("input.mantine-NumberInput-input").first
        kappa.fill("0")  # outside kappa's range (0.5 to 20); the box keeps focus
        note = page.locator(".dst-refused")
        _wait(lambda: note.get_attribute("data-refused") == "kappa", HUNG_S, "the refusal", page)
        assert "kappa not applied: kappa must be in [0.5, 20]" in note.inner_text()
        assert "the loop keeps" in note.inner_text()
        assert _on_screen(page, note)
    finally:
        page.close()


#: Every element of `sel` inside the element `box`: its right edge within the box's content
#: (its right edge less its right padding, where the panel's scrollbar sits) and the box not
#: wider than it shows (nothing cut off at its edge); the offenders' text, or [] if none.
_OVERFLOWING_JS = """([box, sel]) => {
    const b = document.querySelector(box);
    if (!b) return ['no ' + box];
    const right = b.getBoundingClientRect().right - parseFloat(getComputedStyle(b).paddingRight);
    const out = [...b.querySelectorAll(sel)]
        .filter(e => e.getBoundingClientRect().right > right + 0.5)
        .map(e => e.innerText);
    if (b.scrollWidth > b.clientWidth) out.push(box + ' scrolls sideways');
    return out;
}"""


def test_a_long_status_and_trial_list_fit_a_laptop_window(served: str, browser: Browser) -> None:
    """At 1366 x 768 no status item and no trial is cut at the panel's edge (issue 34: the
    status read "single view alo..." and the trial list "#33 s..."). The demo's status
    carries the longest item the app writes (its world, ~620 px on one line); the trial list
    is the page's own tally, rendered by the view's code for 40 trials (the newest shown,
    three-digit times, the longest outcome reason of robot/task.py's and the
    longest mode name) and put in its place."""
    from dsteleop.app.viewer.panel import Trial, TrialTally, tally_html

    page = _open(browser, served, *SMALL_WINDOW)
    try:
        status = page.locator(".dst-status")
        _wait(lambda: "world" in status.inner_text(), HUNG_S, "the demo's world", page)
        assert "single view along" in status.inner_text()
        cut = page.evaluate(_OVERFLOWING_JS, [".dst-status", ".dst-item, .dst-status-line"])
        assert not cut, cut
        tally = TrialTally()
        tally.trials = [Trial(n, n % 3 == 0, "on_table", 100.0 + n, "conf_scalar")
                        for n in range(1, 41)]  # fmt: skip
        cut = page.evaluate(
            """([html, js]) => {
                const old = document.querySelector('.dst-tally');
                old.outerHTML = html;                    // measured before React redraws
                return eval(js)(['.dst-tally', '.dst-trial']);
            }""",
            [tally_html(tally), _OVERFLOWING_JS],
        )
        assert not cut, cut
    finally:
        page.close()


def test_two_tabs_see_one_session_and_the_loop_rate_holds(served: str, browser: Browser) -> None:
    """Two tabs on one served session: the loop's own rate (from its snapshots, as the page
    shows it) stays at least `held_rate_floor` of its 30 Hz, and both tabs show the same tick
    at the same moment.

    The floor is tests/deadlines.py's, 40 %, not the 80 % (24 Hz) this test once asked: two
    software-rendering tabs, the served process and the test share 2 cores, and a loop starved
    beside busy processes kept 57 % (load 14.5), while a loop that waits on its tabs stops or
    falls to a few Hz. The 30 Hz and jitter targets are `dsteleop bench --only viewer`'s."""
    pages = [_open(browser, served, 800, 500) for _ in range(2)]
    try:
        _wait(lambda: all(_status(p).get("rateHz") for p in pages), HUNG_S, "loop rates", pages[0])
        rates: list[float] = []
        offsets: list[float] = []  # tab 2's tick minus tab 1's, at the same moment
        for _ in range(6):
            t0, a = time.monotonic(), _status(pages[0])
            t1, b = time.monotonic(), _status(pages[1])
            rates += [float(x["rateHz"]) for x in (a, b) if x.get("rateHz")]
            if int(b["tick"]) >= int(a["tick"]):  # no task reset in between
                offsets.append(int(b["tick"]) - int(a["tick"]) - 30.0 * (t1 - t0))
            pages[0].wait_for_timeout(500)
        assert len(rates) >= 6
        assert statistics.median(rates) >= held_rate_floor(30.0), rates
        # Both tabs follow the same session: the same tick at the same moment, within
        # half a second (panel updates at 10 Hz, a busy software-rendering browser).
        assert offsets and statistics.median(np.abs(offsets)) <= 15.0, offsets
    finally:
        for p in pages:
            p.close()


def _palm(page: Page) -> tuple[float, ...]:
    """The achieved palm position the page shows [m] (the status's `data-palm-m`)."""
    return tuple(float(v) for v in _status(page)["palmM"].split(","))


def _moving(page: Page, seconds: float = 1.0) -> bool:
    """The palm the page shows moves by more than 1 mm within `seconds`, while tracked."""
    p0 = np.array(_palm(page))
    page.wait_for_timeout(seconds * 1e3)
    st = _status(page)
    return bool(st["status"] == "tracking" and np.abs(np.array(_palm(page)) - p0).max() > 1e-3)


def _halted(page: Page, what: str) -> None:
    """The page says stopped and the commanded speed is 0, then (after 1 s for the arm to
    settle) the palm it shows stays within 0.5 mm of where it is for 2 s (the demo's hand
    moves it by ~0.1 m/s: 200 mm in that time; the palm is shown to 0.1 mm, and the held arm
    settles by a few tenths of a millimetre).

    The demo's trial may end on its own between the page seeing the arm move and the stop
    (on a fast machine it did: `finished`, success): the stop stays latched, and once the
    next trial starts (serve resets `--reset-after` 4 s after an outcome) it shows
    `stopped`; so the wait is for `stopped` itself, within HUNG_S plus that reset."""

    def stopped() -> bool:
        st = _status(page)
        return st["stopped"] == "1" and float(st["cmdMps"]) == 0.0 and st["status"] == "stopped"

    for attempt in range(3):
        _wait(stopped, HUNG_S + 4.0 + 5.0, f"the robot stopped ({what})", page)
        st = _status(page)
        assert "ROBOT STOPPED" in page.locator(".dst-stop").inner_text()
        assert page.get_by_role("button", name="Resume").is_enabled()
        page.wait_for_timeout(1000)
        ticks, palm = int(st["tick"]), _palm(page)
        for _ in range(4):
            page.wait_for_timeout(500)
            st = _status(page)
            assert st["stopped"] == "1" and float(st["cmdMps"]) == 0.0, st
            if st["status"] != "stopped":
                # The trial ended while the arm was held: a utensil let go above the bin
                # falls in by itself (CI, 2026-12-07: `finished`, success (in_bin)), and the
                # next trial's reset puts the arm at home. The stop stays latched (above);
                # the hold is judged again within the next trial.
                break
            assert np.abs(np.subtract(_palm(page), palm)).max() < 5e-4, (what, palm, st)
        else:
            break
        assert attempt < 2, f"every trial ended while held ({what}): {st}"
    # The loop ticks on (2 s, at least held_rate_floor's pace): the stop is the halt, latched.
    assert int(st["tick"]) > ticks + 2.0 * held_rate_floor(30.0), (ticks, st["tick"])


def test_stop_in_the_page_halts_the_robot_until_resume_and_so_do_the_keys(
    served: str, browser: Browser
) -> None:
    """Click "Stop robot" on the served page: the robot halts (the page's palm stays put,
    the command is 0) and stays halted while the demo's hand goes on; Resume drives it again.
    Then the same with the keys: Escape stops, Shift+R resumes."""
    page = _open(browser, served, *SMALL_WINDOW)
    try:
        stop = page.get_by_role("button", name="Stop robot")
        resume = page.get_by_role("button", name="Resume")
        assert _on_screen(page, stop) and _on_screen(page, resume)
        assert resume.is_disabled() and _status(page)["stopped"] == "0"
        assert "Escape" in page.locator(".dst-stop").inner_text()
        _wait(lambda: _moving(page), 60.0, "the arm moving under the demo's hand", page)
        stop.click()
        _halted(page, "the button")
        resume.click()
        _wait(lambda: _status(page)["stopped"] == "0", HUNG_S, "the resume", page)
        _wait(lambda: _moving(page), 60.0, "the arm moving again after Resume", page)
        assert resume.is_disabled()
        page.evaluate("document.activeElement?.blur()")  # the keys go to the page, no box
        page.keyboard.press("Escape")
        _halted(page, "Escape")
        page.keyboard.press("Shift+R")
        _wait(lambda: _status(page)["stopped"] == "0", HUNG_S, "the resume (Shift+R)", page)
        _wait(lambda: _moving(page), 60.0, "the arm moving again after Shift+R", page)
    finally:
        # Never leave the shared session stopped for the other tests.
        with contextlib.suppress(Exception):
            if _status(page)["stopped"] == "1":
                page.get_by_role("button", name="Resume").click()
        page.close()


# ----------------------------------------------------------------------------- camera
# ----------------------------------------------------------------------------- camera

VIDEO = "videos/portrait_fingers_open_close.mp4"  # 540x960 portrait, a hand opening/closing
CANVAS_LEVEL = 60  # the grey canvas of sources without pixels (viewer.panel.camera_image)
# A grey canvas with a drawn hand has a pixel std-dev of about 20 (the demo's: 20.7 at most);
# the frames of this video about 60-66. Twice the canvas's is "clearly" a camera picture.
MIN_PICTURE_STD = 40.0

_IMAGE_BYTES_JS = """async e => {
    try {
        const r = await fetch(e.src);
        const b = new Uint8Array(await r.arrayBuffer());
        let s = "";
        for (let i = 0; i < b.length; i += 8192) {
            s += String.fromCharCode.apply(null, b.subarray(i, i + 8192));
        }
        return btoa(s);
    } catch (err) {
        return null;  // the image was replaced (its blob revoked) meanwhile: read again
    }
}"""


def _camera_img(page: Page) -> Any:
    """The <img> viser renders inside the "Camera" folder (the title's parent panel)."""
    title = page.get_by_text("Camera", exact=True)
    return title.locator("xpath=..").locator("img")


def _decoded(data: bytes) -> np.ndarray[Any, np.dtype[np.uint8]]:
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "not an image"
    return np.asarray(img, dtype=np.uint8)


def _sent_image(page: Page) -> np.ndarray[Any, np.dtype[np.uint8]] | None:
    """The camera image as sent (the JPEG behind the <img>), BGR, or None if not shown yet."""
    img = _camera_img(page)
    if not img.count():
        return None
    data = img.first.evaluate(_IMAGE_BYTES_JS)
    return None if data is None else _decoded(base64.b64decode(data))


def _video_frames(path: Path, width: int, height: int) -> np.ndarray[Any, np.dtype[np.uint8]]:
    """Every frame of the video, downscaled as the view does, BGR."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    frames = []
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            frames.append(cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA))
    finally:
        cap.release()
    assert frames, f"no frames in {path}"
    return np.stack(frames)


def _grey_fraction(img: np.ndarray[Any, np.dtype[np.uint8]]) -> float:
    near = np.abs(img.astype(np.int16) - CANVAS_LEVEL) <= 3
    return float(near.all(axis=-1).mean())


def test_camera_panel_shows_the_videos_pixels(shared_data: Path, browser: Browser) -> None:
    video = shared_data / VIDEO
    if not video.is_file():
        pytest.skip(f"test video not found: {video}")
    with _serve("--source", f"video:{video}") as url:
        page = _open(browser, url)
        try:
            _camera_img(page).first.wait_for(state="attached")
            shown: list[np.ndarray[Any, np.dtype[np.uint8]]] = []

            def read() -> bool:
                img = _sent_image(page)
                if img is not None:
                    shown.append(img)
                return img is not None

            _wait(read, 60.0, "the camera image", page)
            img = shown[-1]
            natural = _camera_img(page).first.evaluate("e => [e.naturalWidth, e.naturalHeight]")
            png = _camera_img(page).first.screenshot()
        finally:
            page.close()
    # The portrait frame scaled to fit the panel's box (not 569 px tall), its aspect kept.
    assert img.shape == (300, 169, 3) and list(natural) == [169, 300], (img.shape, natural)
    # A picture, not the uniform grey canvas (std 0) nor the canvas with a hand drawn on it.
    assert img.std() > MIN_PICTURE_STD, img.std()
    assert _grey_fraction(img) < 0.05
    # ... and this video's picture: close to one of its frames (JPEG, the drawn landmarks),
    # and far closer than the grey canvas is to any frame.
    frames = _video_frames(video, img.shape[1], img.shape[0])
    diff = np.abs(frames.astype(np.int16) - img.astype(np.int16)).mean(axis=(1, 2, 3))
    grey = np.abs(frames.astype(np.int16) - CANVAS_LEVEL).mean(axis=(1, 2, 3))
    assert diff.min() < 12.0, diff.min()
    assert diff.min() < 0.25 * grey.min(), (diff.min(), grey.min())
    # What the page draws is the picture too (an element screenshot of the <img>).
    drawn = _decoded(png)
    assert drawn.std() > MIN_PICTURE_STD and _grey_fraction(drawn) < 0.05, drawn.std()


def _box(page: Page, locator: Any) -> dict[str, float]:
    """A locator's bounding box, read again while the element is being replaced (None)."""
    for _ in range(40):
        box = locator.bounding_box()
        if box is not None:
            return dict(box)
        page.wait_for_timeout(50)
    raise AssertionError(f"no bounding box for {locator}")


def _belief(page: Page) -> dict[str, Any]:
    return dict(
        page.eval_on_selector(
            ".dst-belief",
            """e => ({...e.dataset, rows: [...e.querySelectorAll('.dst-belief-row')].map(
                r => ({...r.dataset}))})""",
        )
    )


def test_the_page_shows_the_belief_and_the_confidence_of_a_goal_it_infers(
    browser: Browser,
) -> None:
    """`serve --goal infer`: one bar per utensil, their probabilities summing to 1 and none
    below the floor, the MAP moving to the person's utensil (the ladle); each gauge's
    confidence in [0, 1]; the Utensil menu offers infer, and telling the robot a utensil from
    it (Reset task) replaces the bars by one line. At 1366 x 768 the belief is on screen,
    inside the panel."""
    with _serve("--source", "demo", "--goal", "infer", "--utensil", "ladle") as url:
        page = _open(browser, url, *SMALL_WINDOW)
        try:
            _wait(lambda: _belief(page)["names"] == "spoon,spatula,ladle", 60.0, "the bars", page)
            # One reading judged whole: once grasped, the place phase's one goal (the bin)
            # replaces the bars, and under load that can happen between two readings.
            seen: list[dict[str, Any]] = []

            def map_on_ladle() -> bool:
                b = _belief(page)
                if b["names"] == "spoon,spatula,ladle" and b["map"] == "ladle":
                    seen.append(b)
                return bool(seen)

            _wait(map_on_ladle, 60.0, "the MAP on the ladle", page)
            b = seen[0]
            assert [r["name"] for r in b["rows"]] == ["spoon", "spatula", "ladle"]
            p = [float(r["p"]) for r in b["rows"]]
            assert sum(p) == pytest.approx(1.0, abs=2e-3) and min(p) >= 0.01 - 5e-4, p
            assert [r["map"] for r in b["rows"]] == ["0", "0", "1"] and 0 <= float(b["cJoint"]) <= 1
            conf = page.eval_on_selector_all(".dst-gauge", "els => els.map(e => e.dataset.c)")
            assert len(conf) == len(DIMS) and all(0.0 <= float(c) <= 1.0 for c in conf), conf
            # (The panel's HTML is replaced ten times a second: a box may be read mid-swap.)
            block = page.locator(".dst-belief >> visible=true").first
            _wait(lambda: _on_screen(page, block), HUNG_S, "the belief on screen", page)
            panel = _box(page, page.locator(".dst-tally").first)  # the panel's width
            box = _box(page, block)
            assert (
                box["x"] >= panel["x"] - 1
                and box["x"] + box["width"] <= panel["x"] + panel["width"] + 1
            )
            utensil = page.get_by_role("combobox").nth(1)
            assert utensil.input_value() == "infer"
            utensil.click()
            page.get_by_role("option", name="spoon", exact=True).click()
            page.get_by_role("button", name="Reset task").click()
            _wait(lambda: _belief(page)["names"] == "", HUNG_S, "a told goal", page)
            assert "told its goal" in page.locator(".dst-belief").inner_text()
            assert all(
                c == ""
                for c in page.eval_on_selector_all(".dst-gauge", "els => els.map(e => e.dataset.c)")
            )
        finally:
            page.close()
