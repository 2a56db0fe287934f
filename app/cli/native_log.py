"""Native libraries' own stderr lines, routed through `logging` at debug level.

MediaPipe (absl's `W0000 ...` lines, TensorFlow Lite's `INFO: Created ... delegate`), the
FFmpeg inside OpenCV (`[mov,mp4,... @ 0x...] moov atom not found`) and OpenCV itself
(`[ WARN:0@0.02] ...`) write to file descriptor 2 from C++, where Python's logging neither
sees nor filters them; no environment variable silences absl before its `InitializeLog()`.
`route_native_stderr()` points descriptor 2 at a pipe for the duration of a command and keeps
Python's own `sys.stderr` on the real stderr: a thread reads the pipe and sends every line
shaped like a native library's log line to the `dsteleop.native` logger at DEBUG (shown with
`dsteleop -v`); any other line passes through unchanged, so nothing else is hidden.

It applies only when `sys.stderr` is the process's own (a command run from a shell); under a
test's output capture it does nothing.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import threading
from collections.abc import Iterator
from typing import IO, cast

log = logging.getLogger("dsteleop.native")

#: The shapes of native log lines: absl/glog (`W0000 00:00:...`), TensorFlow Lite's `INFO:` and
#: LiteRT's `INFO: [file.cc:12]` (mediapipe 1.x), absl's and glog's pre-initialisation notices,
#: FFmpeg's `[name @ 0x...]`, OpenCV's `[ WARN:0@1.2]`.
NATIVE_LINE = re.compile(
    r"^(?:[IWEF]\d{4} \d\d:\d\d:\d\d"
    r"|INFO: Created TensorFlow Lite"
    r"|INFO: \[\w+\.cc:\d+\] "
    r"|WARNING: All log messages before absl::InitializeLog"
    r"|WARNING: Logging before InitGoogle\(\)"
    r"|\[[\w ,.-]+ @ 0x[0-9a-f]+\]"
    r"|\[ *(?:WARN|ERROR|INFO|DEBUG|VERBOSE|FATAL):\d+@"
    r"|pybullet build time)"
)


def is_native_line(line: str) -> bool:
    """Whether `line` looks like a native library's log line (`NATIVE_LINE`)."""
    return NATIVE_LINE.match(line) is not None


def _pump(fd: int, real: IO[str]) -> None:
    """Read the pipe until every writer closed it; route each line (module docstring)."""
    buf = b""
    with os.fdopen(fd, "rb", buffering=0) as pipe:
        while chunk := pipe.read(65536):
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for raw in lines:
                _route(raw.decode("utf-8", errors="replace"), real)
    if buf:
        _route(buf.decode("utf-8", errors="replace"), real)


def _route(line: str, real: IO[str]) -> None:
    if is_native_line(line):
        log.debug("%s", line.rstrip())
    else:
        real.write(line + "\n")
        real.flush()


@contextlib.contextmanager
def route_native_stderr() -> Iterator[None]:
    """Route native stderr lines through logging while the block runs (module docstring).

    Configure logging inside the block, so that its handler writes to the real stderr.
    """
    if sys.stderr is None or sys.stderr is not sys.__stderr__:
        yield
        return
    try:
        cast(IO[str], sys.stderr).flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no usable descriptor 2
        yield
        return
    real = os.fdopen(os.dup(saved), "w", buffering=1, errors="backslashreplace")
    read_fd, write_fd = os.pipe()
    os.dup2(write_fd, 2)
    os.close(write_fd)
    previous = sys.stderr
    sys.stderr = real
    pump = threading.Thread(target=_pump, args=(read_fd, real), name="dsteleop-stderr")
    pump.daemon = True
    pump.start()
    try:
        yield
    finally:
        os.dup2(saved, 2)  # the pipe's last writer closes: the pump reads to its end
        os.close(saved)
        pump.join(timeout=2.0)
        sys.stderr = previous
        with contextlib.suppress(OSError, ValueError):
            real.flush()
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.StreamHandler) and handler.stream is real:
                handler.setStream(previous)
        with contextlib.suppress(OSError, ValueError):
            real.close()
