"""Where a live run's Rerun recording goes (checked when the command line is read; no
`rerun` import here, so parsing stays fast)."""

from __future__ import annotations

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
            if self.path.suffix != ".rrd":
                raise ConfigError(f"--rerun must name a .rrd file, got {self.path}")
            if not self.path.parent.is_dir():
                raise ConfigError(f"--rerun: no such folder: {self.path.parent}")
        if self.connect is not None and not self.connect.startswith(("rerun+http", "rerun")):
            raise ConfigError(
                f"--rerun-connect: expected rerun+http://HOST:PORT/proxy, got {self.connect!r}"
            )
