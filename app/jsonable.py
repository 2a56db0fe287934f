"""Values made JSON-ready: the one sanitiser every writer of JSON uses.

JSON has no NaN and no infinity, and knows neither numpy nor dataclasses. `jsonable` turns a
value into one `json.dumps(..., allow_nan=False)` accepts: non-finite floats become null,
numpy scalars and arrays Python ones, tuples lists, dataclasses dicts of their fields, and
dict keys strings. `finite` does it for one number. Both are pure and import nothing of the
app, so any layer may use them (tests/test_layering.py).

`read_json` is the one reader of a JSON file that a user hands over (a configuration, a
session's metadata, a dataset's info, a tuned best.json): a missing, unreadable or malformed
file is one line (`InputError`, exit 2) that names the option or role it came from and the
file, never a traceback.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from dsteleop.errors import InputError


def finite(x: object) -> float | None:
    """`x` as a finite float, or None (NaN, infinity, or not a number)."""
    try:
        v = float(x)  # type: ignore[arg-type]  # anything float() accepts; else None
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def jsonable(value: object) -> Any:
    """`value` JSON-ready (module docstring); other values (str, int, bool, None) as they are."""
    if isinstance(value, float):  # numpy's float64 too
        return float(value) if math.isfinite(value) else None
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    tolist = getattr(value, "tolist", None)  # numpy scalars and arrays
    if callable(tolist):
        return jsonable(tolist())
    return value


def read_json(path: str | Path, role: str = "") -> Any:
    """The parsed content of the JSON file at `path`.

    Args:
        path: the file.
        role: what the file is to the command (`--config`, "session metadata"), put before
            the path in the message; empty for none.

    Raises:
        InputError: the file is missing, unreadable, not UTF-8 or not JSON; one line:
            "ROLE PATH: file not found" or "ROLE PATH: not a JSON file (REASON)".
    """
    where = f"{role} {path}" if role else str(path)
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{where}: file not found") from None
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise InputError(f"{where}: not a JSON file ({exc})") from None
