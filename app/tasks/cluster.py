"""Tasks on a Ray cluster (`RayExecutor`, an `app.tasks.executor.Cluster`): the one module of
dsteleop that imports Ray (used by `dsteleop tune`, `dsteleop sim --sweep` and their benchmarks
only).

    address None       `ray.init()` starts a local cluster on this machine: `workers` CPUs
                       (default: every core), bound to the loopback interface, with a
                       per-run authentication token in the environment (nothing written to
                       the home folder), no dashboard, usage statistics off, no probe of
                       cloud metadata services (`_cluster_home`), the workers' output kept
                       in Ray's log folder (/tmp/ray) instead of the terminal: it connects
                       to nothing but 127.0.0.1
    "auto"             the cluster this machine is a node of (`ray start` ran here)
    "ray://HOST:PORT"  a remote cluster through Ray Client (its head's client port, 10001
                       by default)
    "HOST:PORT"        a cluster's head (GCS) address, from a machine of that cluster

A task uses one CPU; Ray retries a task whose worker died once, never one that raised. A task
that raised comes back as `TaskError` with the original error's type and message. Nothing here
contacts any other host than `address`: before Ray is asked, a TCP connection to HOST:PORT is
tried (5 s), so an unreachable address is one line instead of Ray's own minute of retries.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import socket
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from dsteleop.app.tasks.executor import TaskError, describe_error
from dsteleop.errors import ConfigError, InputError

log = logging.getLogger(__name__)

#: The local cluster's object store [bytes]: trial arguments and results are small (a session
#: is a few MB); Ray's default, 30 % of the memory, is far more than needed.
OBJECT_STORE_BYTES = 256 * 1024 * 1024
CONNECT_TIMEOUT_S = 5.0
#: The workers' environment: one BLAS thread per task (a task is one core's work).
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def parse_address(address: str | None) -> tuple[str, int] | None:
    """(host, port) of a `ray://HOST:PORT` or `HOST:PORT` address; None for a local cluster
    or `auto`.

    Raises:
        ConfigError: the address is none of the forms of the module docstring.
    """
    if address is None or address == "auto":
        return None
    rest = address.removeprefix("ray://")
    host, sep, port_s = rest.rpartition(":")
    if not sep or not host or not port_s.isdigit() or not 0 < int(port_s) < 65536:
        raise ConfigError(f"--address {address!r}: expected ray://HOST:PORT, HOST:PORT or auto")
    return host.strip("[]"), int(port_s)


def check_reachable(address: str | None) -> None:
    """A TCP connection to the address's HOST:PORT opens (nothing for a local cluster; for
    `auto`, the address Ray would use: $RAY_ADDRESS, else the cluster last started here).

    Raises:
        InputError: it does not (one line with the reason).
    """
    target = _auto_address() if address == "auto" else parse_address(address)
    if target is None:
        return
    try:
        with socket.create_connection(target, timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc) or type(exc).__name__
        where = f"{address} ({target[0]}:{target[1]})" if address == "auto" else address
        raise InputError(
            f"--address {where}: cannot reach a Ray cluster there ({reason})"
        ) from None


def _auto_address() -> tuple[str, int]:
    """Where `auto` points: Ray's own lookup (Ray 2.60's `canonicalize_bootstrap_address`)."""
    from ray._private.services import canonicalize_bootstrap_address

    try:
        found = canonicalize_bootstrap_address("auto")
    except Exception as exc:  # Ray raises ConnectionError, ValueError, ... when it finds none
        raise InputError(f"--address auto: {describe_error(exc)}") from None
    if not found:
        raise InputError("--address auto: no Ray cluster runs on this machine (ray start)")
    host, _, port = str(found).rpartition(":")
    return host.strip("[]"), int(port)


class RayExecutor:
    """Tasks on a Ray cluster (module docstring). Close it (or use it as a context manager)
    to disconnect, and to stop a local cluster it started.

    Args:
        address: None (a local cluster), "auto", "ray://HOST:PORT" or "HOST:PORT".
        workers: CPUs of a local cluster (None: every core); ignored with an address.
    """

    def __init__(self, address: str | None = None, workers: int | None = None) -> None:
        if workers is not None and workers < 1:
            raise ConfigError(f"--workers must be >= 1, got {workers}")
        self.address = address
        self.local = address is None
        _quiet_environment(local=self.local)
        check_reachable(address)
        import ray

        self._ray = ray
        self._remote: dict[Callable[..., Any], Any] = {}
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "logging_level": logging.ERROR,
        }
        if self.local:
            kwargs.update(
                num_cpus=workers or os.cpu_count() or 1,
                object_store_memory=OBJECT_STORE_BYTES,
            )
        else:
            # A cluster started elsewhere: its workers get the thread limits this way.
            kwargs["runtime_env"] = {"env_vars": dict(WORKER_ENV)}
            if address is not None and address.startswith("ray://"):
                # Ray Client accepts fewer options.
                kwargs = {"logging_level": logging.ERROR, "runtime_env": kwargs["runtime_env"]}
        self._home: tempfile.TemporaryDirectory[str] | None = None
        try:
            with warnings.catch_warnings(), self._cluster_home():
                warnings.simplefilter("ignore")
                ray.init(address=address, **kwargs)
        except (ConnectionError, RuntimeError, TimeoutError, ValueError, SystemExit) as exc:
            self.close()
            where = "a local Ray cluster" if self.local else f"the Ray cluster at {address}"
            raise InputError(f"cannot start or join {where}: {describe_error(exc)}") from None
        self.capacity = max(1, int(ray.cluster_resources().get("CPU", 1)))  # type: ignore[no-untyped-call]
        log.debug("ray: %s, %d CPUs", address or "local cluster", self.capacity)

    @contextlib.contextmanager
    def _cluster_home(self) -> Iterator[None]:
        """While a local cluster starts (its processes inherit the environment), HOME is a
        folder of its own holding `ray_bootstrap_config.yaml` for a local provider.

        Ray 2.60 starts a reduced dashboard even without one, whose usage-statistics module
        looks for that file in the home folder and, when it is missing, asks three cloud
        metadata services which cloud it runs on (169.254.169.254 and a DNS look-up of
        metadata.google.internal) - even with usage statistics off. With the file it reads
        the provider from it and contacts nothing.
        """
        if not self.local:
            yield
            return
        self._home = tempfile.TemporaryDirectory(prefix="dsteleop-ray-")
        (Path(self._home.name) / "ray_bootstrap_config.yaml").write_text(
            "# written by dsteleop (tune, sim --sweep) for its local Ray cluster\n"
            "provider:\n  type: local\n"
        )
        before = os.environ.get("HOME")
        # The workers keep the user's cache folder (where the compiled arbitration kernels
        # are, arbitration/jit.py): without it each worker would compile them again.
        cache_before = os.environ.get("XDG_CACHE_HOME")
        os.environ["XDG_CACHE_HOME"] = cache_before or str(Path.home() / ".cache")
        os.environ["HOME"] = self._home.name
        try:
            yield
        finally:
            for name, value in (("HOME", before), ("XDG_CACHE_HOME", cache_before)):
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> dict[str, Any]:
        """Where the tasks run, for the outputs."""
        return {
            "cluster": "local" if self.local else self.address,
            "cpus": self.capacity,
            "nodes": sum(bool(n.get("Alive")) for n in self._ray.nodes()),  # type: ignore[no-untyped-call]
            "ray": self._ray.__version__,
        }

    def submit(self, fn: Callable[..., Any], *args: Any) -> Any:
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._ray.remote(num_cpus=1, max_retries=1, retry_exceptions=False)(fn)
            self._remote[fn] = remote
        return remote.remote(*args)

    def ready(self, handles: Sequence[Any], timeout_s: float) -> list[Any]:
        if not handles:
            return []
        ready, _ = self._ray.wait(list(handles), num_returns=1, timeout=timeout_s)
        if ready:  # and every other one that is done by now
            ready, _ = self._ray.wait(list(handles), num_returns=len(handles), timeout=0)
        return list(ready)

    def result(self, handle: Any) -> Any:
        from ray.exceptions import RayError, RayTaskError

        try:
            return self._ray.get(handle)
        except RayTaskError as exc:
            cause = exc.cause if isinstance(exc.cause, BaseException) else exc
            raise TaskError(describe_error(cause)) from None
        except RayError as exc:  # the worker or its node died, the object was lost, ...
            raise TaskError(describe_error(exc)) from None

    def share(self, value: Any) -> Any:
        return self._ray.put(value)

    def close(self) -> None:
        if self._ray.is_initialized():
            self._ray.shutdown()
        if self._home is not None:
            self._home.cleanup()
            self._home = None


def _quiet_environment(local: bool) -> None:
    """Ray's settings that must be in the environment before it is imported."""
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"  # no usage report, no prompt
    for k, v in WORKER_ENV.items():
        os.environ.setdefault(k, v)  # a local cluster's workers inherit this environment
    if local:
        # Ray finds the node's address from the interface that would route to a public
        # address; on a single machine that is not needed: the loopback interface is used
        # (this variable makes Ray do so on Linux too).
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        # Ray >= 2.5x protects a new local cluster with a token, by default written to
        # ~/.ray/auth_token; a per-run token in the environment (inherited by the cluster's
        # processes) protects it the same way and leaves nothing behind.
        # One token per process (Ray caches it): a second local cluster uses the same.
        os.environ.setdefault("RAY_AUTH_MODE", "token")
        os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(32))
