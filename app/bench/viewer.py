"""Bench group `viewer`: the live loop's rate and jitter with 0, 1 and 5 viewers connected.

Each configuration builds the live demo session in this process exactly as `dsteleop serve
--source demo` does (the loop on the monotonic clock, tracking in its threads, the viewer
thread with its Viser server on a free local port), connects N clients from a separate
process, lets it settle, then measures for a fixed time:

    loop rate      ticks per second of loop time over the window [Hz]
    jitter         start-time jitter of every tick (actual - scheduled start) [ms]: p50, p99
    tick           tick duration [ms]: p50, p99
    bytes/s        bytes received per client per second (websocket payload)

Two kinds of client: `ws` (a websocket client speaking Viser's protocol that receives and
counts every message, like a tab whose rendering costs nothing: isolates the server's own
cost) and `browser` (headless Chromium pages on the system Chromium, rendering the scene with
software WebGL: the full cost, on the same two cores as the loop). The browser kind runs only
when /usr/bin/chromium exists.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from dsteleop.app.session.schema import TickRecord
from dsteleop.errors import InputError

if TYPE_CHECKING:
    from dsteleop.app.loop import TeleopLoop

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = (
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
)


class _Collector:
    """Collects every snapshot's timing from its own subscription (tiny consumer)."""

    def __init__(self, loop: TeleopLoop) -> None:
        self._sub = loop.broadcaster.subscribe()
        self.rows: list[tuple[int, float, float, float]] = []
        self._on = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            snap: TickRecord | None = self._sub.wait(0.2)
            if snap is not None and self._on.is_set():
                t = snap.timing
                self.rows.append(
                    (
                        int(snap.k),
                        float(snap.t_s),
                        t.get("jitter_ms", np.nan),
                        t.get("tick_ms", np.nan),
                    )
                )

    def measure(self, seconds: float) -> dict[str, Any]:
        dropped0 = self._sub.dropped
        self._on.set()
        time.sleep(seconds)
        self._on.clear()
        self._stop.set()
        self._thread.join()
        self._sub.close()
        a = np.asarray(self.rows, dtype=np.float64)
        if len(a) < 10:
            raise InputError("bench viewer: the loop published fewer than 10 ticks")
        dk = np.diff(a[:, 0])
        ok = dk > 0  # a task reset restarts ticks at 0: leave that step out
        rate = float(dk[ok].sum() / np.diff(a[:, 1])[ok].sum())
        jit, dur = a[:, 2], a[:, 3]
        return {
            "loop_rate_hz": round(rate, 2),
            "jitter_ms": {
                "p50": round(float(np.nanmedian(jit)), 3),
                "p99": round(float(np.nanpercentile(jit, 99)), 3),
                "max": round(float(np.nanmax(jit)), 3),
            },
            "tick_ms": {
                "p50": round(float(np.nanmedian(dur)), 3),
                "p99": round(float(np.nanpercentile(dur, 99)), 3),
            },
            "ticks": len(a),
            "ticks_missed_by_bench": int(self._sub.dropped - dropped0),
        }


def _clients_cmd(kind: str, url: str, n: int, seconds: float) -> list[str]:
    return [
        sys.executable,
        "-m",
        "dsteleop.app.bench.viewer",
        "--client",
        kind,
        "--url",
        url,
        "--n",
        str(n),
        "--seconds",
        f"{seconds:.3f}",
    ]


def run_config(
    clients: int, kind: str, seconds: float, settle_s: float, scene_hz: float = 30.0
) -> dict[str, Any]:
    """One configuration: the demo session, `clients` clients of `kind`, measured."""
    from dsteleop.app.compose import LoopOptions, build
    from dsteleop.app.compose.options import RESET_AFTER_S
    from dsteleop.app.compose.root import hand_mapping
    from dsteleop.app.loop import LoopConfig
    from dsteleop.app.loop.timing import raise_priority
    from dsteleop.app.viewer.server import Viewer, ViewerConfig

    raise_priority()  # as `dsteleop serve` does

    load_before = round(os.getloadavg()[0], 2)  # other work on this shared machine
    # As `dsteleop serve` builds it: the task resets a few seconds after each outcome.
    loop_cfg = LoopConfig(reset_after_s=RESET_AFTER_S)
    built = build(LoopOptions.of("demo", loop_cfg), realtime=True, export_scene=True)
    loop = built.loop
    viewer = Viewer(
        loop.broadcaster,
        loop.controls,
        scene=loop.task.scene(),
        config=ViewerConfig(port=0, scene_hz=scene_hz),
        arbitration=loop.config.arbitration,
        source="demo",
        mapping=hand_mapping(loop.hand.mapping_config()),
    )
    viewer.start()
    runner = threading.Thread(target=loop.run, name="bench-loop", daemon=True)
    runner.start()
    proc = None
    try:
        if clients:
            proc = subprocess.Popen(
                _clients_cmd(kind, viewer.url, clients, settle_s + seconds + 2.0),
                stdout=subprocess.PIPE,
                text=True,
            )
        time.sleep(settle_s)
        if clients:
            deadline = time.monotonic() + 60.0
            while viewer.clients < clients and time.monotonic() < deadline:
                time.sleep(0.2)
        collector = _Collector(loop)
        out = collector.measure(seconds)
        out["clients"] = clients
        out["scene_hz"] = scene_hz
        out["load_avg_1min_before"] = load_before
        out["viewer_update_ms_p99"] = round(float(np.percentile(viewer.stats.update_ms, 99)), 2)
        if proc is not None:
            text, _ = proc.communicate(timeout=seconds + settle_s + 90.0)
            per_client = json.loads(text.strip().splitlines()[-1])
            out["bytes_per_s_per_client"] = per_client
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        loop.stop()
        runner.join(timeout=5.0)
        viewer.close()
        loop.close()
    return out


def run(quick: bool = False) -> dict[str, Any]:
    """Bench entry point (`dsteleop bench --only viewer`)."""
    seconds, settle = (6.0, 4.0) if quick else (20.0, 6.0)
    kinds = ["ws"] + (["browser"] if CHROMIUM.exists() else [])
    results: dict[str, Any] = {}
    for kind in kinds:
        for n in (0, 1, 5):
            if kind == "browser" and n == 0:
                continue  # same as ws with 0 clients
            key = f"{kind}_{n}" if n else "no_clients"
            results[key] = run_config(n, kind, seconds, settle)
    return {
        "viewer": {
            "window_s": seconds,
            "target": "30 Hz held, p99 jitter <= 5 ms with 5 clients",
            "cpus": os.cpu_count(),
            **results,
        }
    }


# ----------------------------------------------------------------------------- clients


async def _ws_clients(url: str, n: int, seconds: float) -> list[float]:
    import viser
    import websockets

    ws_url = url.replace("http://", "ws://")
    counts = [0] * n
    marks: list[tuple[float, int] | None] = [None] * n

    async def one(i: int) -> None:
        async with websockets.connect(
            ws_url,
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            max_size=None,
            compression=None,
        ) as ws:
            t_end = time.monotonic() + seconds
            t_start = time.monotonic() + min(4.0, seconds / 3)  # after the initial scene
            while (now := time.monotonic()) < t_end:
                try:
                    msg = await asyncio.wait_for(ws.recv(), timeout=t_end - now)
                except asyncio.TimeoutError:
                    break
                if now >= t_start:
                    if marks[i] is None:
                        marks[i] = (now, 0)
                    counts[i] += len(msg)
            m = marks[i]
            marks[i] = None if m is None else (time.monotonic() - m[0], counts[i])

    await asyncio.gather(*(one(i) for i in range(n)))
    return [m[1] / m[0] if m and m[0] > 0 else 0.0 for m in marks]


def _browser_clients(url: str, n: int, seconds: float) -> list[float]:
    from playwright.sync_api import sync_playwright

    counts = [0] * n
    counting = threading.Event()

    def watch(i: int) -> Any:
        def on_socket(ws: Any) -> None:
            def on_frame(payload: bytes | str) -> None:
                if counting.is_set():
                    counts[i] += len(payload)

            ws.on("framereceived", on_frame)

        return on_socket

    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=list(CHROMIUM_ARGS)
        )
        pages = []
        for i in range(n):
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.on("websocket", watch(i))
            page.goto(url)
            pages.append(page)
        t_end = time.monotonic() + seconds
        settle = min(6.0, seconds / 3)
        pages[0].wait_for_timeout(settle * 1e3)  # playwright events flow while waiting
        counting.set()
        t0 = time.monotonic()
        pages[0].wait_for_timeout(max(0.0, t_end - time.monotonic()) * 1e3)
        dt = time.monotonic() - t0
        counting.clear()
        browser.close()
    return [c / dt for c in counts]


def _client_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--client", choices=("ws", "browser"), required=True)
    ap.add_argument("--url", required=True)
    ap.add_argument("--n", type=int, required=True)
    ap.add_argument("--seconds", type=float, required=True)
    a = ap.parse_args(argv)
    if a.client == "ws":
        rates = asyncio.run(_ws_clients(a.url, a.n, a.seconds))
    else:
        rates = _browser_clients(a.url, a.n, a.seconds)
    out = {"median": round(float(np.median(rates)))} if rates else {"median": None}
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(_client_main(sys.argv[1:]))
