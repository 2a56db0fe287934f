"""How the arbitration maths is compiled: `kernel`, numba's nopython compiler, cached on disk.

The maths of this package (SO(3), eq 1-8) is written once, as loops over plain floats, and
numba compiles it to machine code. One tick of a batch is then one call whatever the batch
size: the 30 Hz loop (a batch of one) pays no per-operation interpreter cost, the simulation
study (thousands of trajectories) makes one pass over its rows.

Compiled code is cached on disk, so only the first run after an install (or after the
sources change) compiles; `dev.sh` does that at install. The cache folder is named by a hash
of this package's sources (its `modes/` too): numba checks only the file of the function it
loads, and a kernel that inlined a helper from another module would otherwise run the
helper's old code after an edit. The cache is under ~/.cache/dsteleop/numba (or
$XDG_CACHE_HOME), or in $NUMBA_CACHE_DIR when that is set.

Conventions for the compiled functions: arguments are float64 arrays, C-contiguous and
writable (`as_input`), and Python floats and ints; a function of one dimension takes scalars,
a function of one state takes the batch's arrays and the state's row in them (it reads row
`a` and writes row `m`), and its batch form loops over a flattened batch.

What makes a compiled tick slow is not what makes numpy slow. Every slice of an array
(`R[m]`) is a new array whose reference count compiled code updates with an atomic
instruction, and an array that a helper uses after a branch stays counted for every call:
with views of each row, a batched tick spent about a quarter of its time on reference
counts. So functions of one state index rows instead of slicing them, and read their rows
before they branch (`se3.log_relative_of` forms the product, then takes its logarithm from
the 9 floats).
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np
from numpy.typing import NDArray


def _cache_dir() -> Path:
    digest = hashlib.sha256()
    root = Path(__file__).parent
    for f in sorted(root.rglob("*.py")):  # the modes' plug-ins too
        digest.update(str(f.relative_to(root)).encode())
        digest.update(f.read_bytes())
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        return Path(user) / f"dsteleop-{digest.hexdigest()[:16]}"
    base = os.environ.get("XDG_CACHE_HOME")
    root = Path(base) if base else Path.home() / ".cache"
    return root / "dsteleop" / "numba" / digest.hexdigest()[:16]


def _configure() -> Any:
    import numba

    # Read when a function is decorated (its cache is located then), so set before any is.
    numba.config.CACHE_DIR = str(_cache_dir())  # type: ignore[attr-defined]
    return numba


_numba = _configure()

#: The decorator of every compiled function: nopython, cached, releases the GIL (a viewer or
#: a recorder thread runs while the loop computes), numpy's float semantics (x / 0 is inf or
#: nan, as in the rest of the code, not an exception), and inlined into its callers (where a
#: call costs more than the maths: a tick of 1000 rows took 3.2 ms instead of 2.0). Inlining
#: makes the first compilation long (~35 s for the package on a 2-core Xeon), once.
_compile = _numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")

_F = TypeVar("_F", bound=Callable[..., Any])


def kernel(fn: _F) -> _F:
    """Compile `fn` (the decorator of every compiled function, above)."""
    return cast(_F, _compile(fn))


def as_input(
    x: Any, batch: tuple[int, ...], vector_axes: int, shared: bool = True
) -> NDArray[np.float64]:
    """An array (..., *tail) broadcast to `batch`, flattened to (M', *tail), for a compiled
    function: M' = 1 when it has no batch of its own (one row shared by every row) and
    `shared`, else M = prod(batch). C-contiguous and writable, so that numba compiles one
    version of each function."""
    if (
        type(x) is np.ndarray
        and len(batch) == 1
        and x.ndim == 1 + vector_axes
        and x.shape[0] == batch[0]
        and x.dtype == np.float64
        and x.flags.c_contiguous
        and x.flags.writeable
    ):
        return x  # already (M, *tail) as compiled functions take it (the common case, fast)
    a = np.asarray(x, dtype=np.float64)
    lead = a.shape[: a.ndim - vector_axes]
    tail = a.shape[a.ndim - vector_axes :]
    if lead != batch and not (shared and math.prod(lead) == 1):
        a = np.broadcast_to(a, (*batch, *tail))
    if not (a.flags.c_contiguous and a.flags.writeable):
        a = np.array(a, dtype=np.float64, order="C")
    return a.reshape(math.prod(a.shape[: a.ndim - vector_axes]), *tail)
