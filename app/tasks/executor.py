"""Where tasks run: the one seam between a computation that hands out tasks (a tuning campaign,
a sweep's cells, a held-out evaluation) and what runs them.

    Executor      submit(fn, *args) -> handle at once; ready(handles, timeout_s) -> the ones
                  done; result(handle) -> the value, or TaskError; share(value) -> a value every
                  task can read (a cluster's object store); capacity: tasks at once
    Cluster       an Executor that is opened and closed (a context manager), says where its
                  tasks run (`describe`) and whether that is this machine (`local`)
    LocalExecutor a Cluster of one: every task runs in this process when submitted
    RayExecutor   Ray tasks on a local or remote cluster (`app.tasks.cluster`)

A task that raises, or whose worker dies, comes back as `TaskError` with one line saying what
happened (`describe_error`): the caller decides whether that fails a trial, a cell or the run.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol


class TaskError(Exception):
    """A task raised, or its worker died; the message says what happened, in one line."""


class Executor(Protocol):
    """Where tasks run (module docstring)."""

    @property
    def capacity(self) -> int: ...

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any: ...

    def ready(self, handles: Sequence[Any], timeout_s: float) -> list[Any]: ...

    def result(self, handle: Any) -> Any: ...

    def share(self, value: Any) -> Any: ...


class Cluster(Executor, Protocol):
    """An executor that is opened and closed (module docstring)."""

    @property
    def local(self) -> bool: ...

    def describe(self) -> dict[str, Any]: ...

    def close(self) -> None: ...

    def __enter__(self) -> Cluster: ...

    def __exit__(self, *exc: object) -> None: ...


class LocalExecutor:
    """Runs every task at once in this process, one at a time (no cluster)."""

    capacity = 1
    local = True

    def __init__(self) -> None:
        self._done: dict[int, tuple[bool, Any]] = {}
        self._next = 0

    def submit(self, fn: Callable[..., Any], *args: Any) -> int:
        handle = self._next
        self._next += 1
        try:
            self._done[handle] = (True, fn(*args))
        except Exception as exc:  # a task that raises comes back as a TaskError, as on a cluster
            self._done[handle] = (False, describe_error(exc))
        return handle

    def ready(self, handles: Sequence[Any], timeout_s: float) -> list[Any]:
        return list(handles)

    def result(self, handle: Any) -> Any:
        ok, value = self._done.pop(handle)
        if not ok:
            raise TaskError(value)
        return value

    def share(self, value: Any) -> Any:
        return value

    def describe(self) -> dict[str, Any]:
        return {"cluster": "this process", "cpus": 1}

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> LocalExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def describe_error(exc: BaseException) -> str:
    """An exception in one line: its type and the first line of its message."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")
