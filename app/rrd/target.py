"""Where a live run's Rerun recording goes (checked when the command line is read; no
`rerun` import here, so parsing stays fast)."""

from __future__ import annotations

import socket
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from dsteleop.errors import ConfigError

#: Where `--rerun-connect` without an address streams to: a Rerun viewer on this machine.
DEFAULT_ADDR = "rerun+http://127.0.0.1:9876/proxy"


@dataclass(frozen=True)
class RerunTarget:
    """Where a live run's recording goes: a file, a viewer, or both.

    Attributes:
        path: an .rrd file to write, or None.
        connect: a viewer's gRPC address (`rerun+http://host:port/proxy`), or None.
    """

    path: Path | None = None
    connect: str | None = None

    def __post_init__(self) -> None:
        if self.path is None and self.connect is None:
            raise ConfigError("a Rerun target needs --rerun FILE.rrd or --rerun-connect")
        if self.path is not None:
            check_rrd_path(self.path)
        if self.connect is not None and not self.connect.startswith(("rerun+http", "rerun")):
            raise ConfigError(
                f"--rerun-connect: expected rerun+http://HOST:PORT/proxy, got {self.connect!r}"
            )


def check_rrd_path(path: Path) -> Path:
    """`--rerun FILE.rrd`: an .rrd file name in a folder that exists, not a folder.

    Raises:
        ConfigError: one line saying which.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ConfigError(f"--rerun must name a .rrd file, got {path}")
    if path.is_dir():
        raise ConfigError(f"--rerun must name a file, got the folder {path}")
    if not path.parent.is_dir():
        raise ConfigError(f"--rerun: no such folder: {path.parent}")
    return path


def viewer_listening(addr: str, timeout_s: float = 0.5) -> bool:
    """Whether something accepts a TCP connection at a `--rerun-connect` address (a Rerun
    viewer, started first, listens there); False for an address without host and port."""
    url = urllib.parse.urlsplit(addr.replace("rerun+", "", 1))
    try:
        host, port = url.hostname, url.port
    except ValueError:
        return False
    if host is None or port is None:
        return False
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False
