"""What the robot link's live tests set up: free loopback ports, link files, `dsteleop
robot-sim` as a child process, and a Zenoh router as a child process (eclipse-zenoh itself in
router mode, as the `zenohd` binary runs it; no scouting, 127.0.0.1 only)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
READY = "robot-sim: ("  # robot-sim's log line once its session and simulation are up

#: A Zenoh router on the endpoint in argv[1] until its standard input closes.
ROUTER_SCRIPT = """
import json, sys, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(c)
print("router up", flush=True)
sys.stdin.read()
session.close()
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def link_file(tmp_path: Path, port: int, **extra: Any) -> Path:
    """A link file with the defaults' shape (the far end listens, the near end connects) on
    `port`, and `extra` fields."""
    ep = f"tcp/127.0.0.1:{port}"
    data = {"far": {"listen": [ep]}, "near": {"connect": [ep]}, "connect_timeout_s": 5.0, **extra}
    f = tmp_path / f"link-{port}.json"
    f.write_text(json.dumps(data))
    return f


class Far:
    """`dsteleop robot-sim` in a child process; its stderr collected in a thread."""

    def __init__(self, config: Path) -> None:
        self.proc = subprocess.Popen(
            [*CLI, "robot-sim", "--zenoh", str(config)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: list[str] = []
        self._ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        if not self._ready.wait(120):
            self.proc.kill()
            raise AssertionError("robot-sim did not start: " + "".join(self.lines))

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            if READY in line:
                self._ready.set()

    def terminate(self) -> dict[str, Any]:
        """SIGTERM; robot-sim's JSON summary."""
        self.proc.send_signal(signal.SIGTERM)
        out, _ = self.proc.communicate(timeout=30)
        assert self.proc.returncode == 0, "".join(self.lines)
        result: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
        return result

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait()


class Router:
    """A Zenoh router on tcp/127.0.0.1:`port` in a child process (`ROUTER_SCRIPT`)."""

    def __init__(self, port: int) -> None:
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", ROUTER_SCRIPT, self.endpoint],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if "router up" not in line:
            self.close()
            raise AssertionError(f"the Zenoh router did not start: {line!r}")

    def close(self) -> None:
        """Close its standard input (it closes its session and exits); kill it if it hangs."""
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
