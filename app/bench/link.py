"""Bench group `link`: the robot link over Zenoh, two processes on loopback.

Starts `dsteleop robot-sim --zenoh` (the PyBullet arm at the far end) in a child process on a
free 127.0.0.1 port, drives it from this process through `ZenohRobot` at 30 Hz for 60 s (10 s
with --quick), a side-to-side palm motion, then stops it with SIGTERM and reads its summary.
Reports the link latency (a command's source stamp, taken just before the near end publishes
it, to the far end setting its target: one clock, one machine) p50/p95/p99/max, the near
end's time to clamp, encode and publish a command, the age of the newest robot state when
the loop reads it (p50/p99), and what the far end dropped.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from dsteleop.app.bench import percentiles_us
from dsteleop.app.link.config import read_link_config
from dsteleop.app.link.near import ZenohRobot
from dsteleop.arbitration import HandState
from dsteleop.errors import InputError

RATE_HZ = 30.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run(quick: bool = False) -> dict[str, Any]:
    seconds = 10.0 if quick else 60.0
    ep = f"tcp/127.0.0.1:{_free_port()}"
    with tempfile.TemporaryDirectory(prefix="dsteleop-bench-link-") as tmp:
        cfg = Path(tmp) / "link.json"
        cfg.write_text(
            json.dumps(
                {"far": {"listen": [ep]}, "near": {"connect": [ep]}, "connect_timeout_s": 10}
            )
        )
        far = subprocess.Popen(
            [sys.executable, "-m", "dsteleop.app.cli.main", "robot-sim", "--zenoh", str(cfg)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            ready = threading.Event()

            def read_stderr() -> None:
                assert far.stderr is not None
                for line in far.stderr:
                    if "robot-sim: (" in line:
                        ready.set()

            threading.Thread(target=read_stderr, daemon=True).start()
            if not ready.wait(120):
                raise InputError("bench link: robot-sim did not start within 120 s")
            near = _drive(read_link_config(cfg), seconds)
            far.send_signal(signal.SIGTERM)
            out, _ = far.communicate(timeout=60)
        finally:
            if far.poll() is None:
                far.kill()
                far.wait()
    summary = json.loads(out.strip().splitlines()[-1])
    return {
        "link": {
            "seconds": seconds,
            "rate_hz": RATE_HZ,
            "endpoint": ep,
            "latency_ms": summary["latency_ms"],
            "applied": summary["applied"],
            "dropped_stale": summary["dropped_stale"],
            "dropped_out_of_order": summary["dropped_out_of_order"],
            **near,
        }
    }


def _drive(config: Any, seconds: float) -> dict[str, Any]:
    robot = ZenohRobot(config)
    try:
        t0 = time.monotonic()
        X0 = robot.reset(0.0).X
        publish_s: list[float] = []
        age_s: list[float] = []
        k = 0
        next_t = time.monotonic()
        while (now := time.monotonic()) - t0 < seconds:
            st = robot.state(now - t0)
            if st is not None:
                age_s.append(now - t0 - st.stamp_s)
            dy = 0.05 * np.sin(2 * np.pi * 0.5 * (now - t0))
            X = HandState(X0.position + np.array([0.0, dy, 0.0]), X0.rotation, X0.openness)
            a = time.perf_counter()
            robot.apply(X, k, now - t0)
            publish_s.append(time.perf_counter() - a)
            k += 1
            next_t += 1.0 / RATE_HZ
            time.sleep(max(0.0, next_t - time.monotonic()))
        ages = np.array(age_s) * 1e3
        return {
            "sent": robot.sent,
            "near_apply_us": percentiles_us(publish_s),
            "state_age_ms": {
                "p50": round(float(np.percentile(ages, 50)), 3),
                "p99": round(float(np.percentile(ages, 99)), 3),
                "n": int(ages.size),
            },
        }
    finally:
        robot.close()
