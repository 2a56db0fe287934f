"""The one JSON sanitiser (app/jsonable.py): what JSON cannot hold becomes what it can."""

from __future__ import annotations

import ast
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from dsteleop.app.jsonable import finite, jsonable, read_json
from dsteleop.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class _Inner:
    gain: float
    steps: tuple[int, ...]


@dataclass(frozen=True)
class _Outer:
    name: str
    inner: _Inner
    weights: np.ndarray


def test_non_finite_floats_become_null_and_finite_ones_stay() -> None:
    got = jsonable([math.nan, math.inf, -math.inf, np.float64(np.nan), np.float32(0.5), 1.25])
    assert got == [None, None, None, None, 0.5, 1.25]
    assert all(type(v) is float for v in got[4:])


def test_numpy_tuples_dataclasses_and_keys_become_plain_json() -> None:
    value = {
        1: np.int64(3),
        "flag": np.bool_(True),
        "arr": np.array([[1.0, np.nan], [np.inf, 2.0]]),
        "t": (1, (2, 3)),
        "dc": _Outer("a", _Inner(np.float64(-np.inf), (1, 2)), np.arange(2)),
    }
    got = jsonable(value)
    assert got == {
        "1": 3,
        "flag": True,
        "arr": [[1.0, None], [None, 2.0]],
        "t": [1, [2, 3]],
        "dc": {"name": "a", "inner": {"gain": None, "steps": [1, 2]}, "weights": [0, 1]},
    }
    assert type(got["1"]) is int and type(got["flag"]) is bool
    json.dumps(got, allow_nan=False)  # accepted as it is


def test_plain_values_pass_through() -> None:
    for v in ("text", 7, True, None, 0.0):
        assert jsonable(v) == v and type(jsonable(v)) is type(v)


@pytest.mark.parametrize(
    ("x", "want"),
    [(1.5, 1.5), (np.float32(2.0), 2.0), (np.int64(4), 4.0), ("3", 3.0), (math.nan, None),
     (-math.inf, None), (None, None), ("x", None), (object(), None)],
)  # fmt: skip
def test_finite(x: object, want: float | None) -> None:
    assert finite(x) == want


def test_no_module_defines_a_sanitiser_of_its_own() -> None:
    """The copies this module replaced stay gone: no function elsewhere is named like one."""
    names = {"jsonable", "_jsonable", "json_ready", "json_safe", "clean", "_finite", "num"}
    found = []
    for folder in ("app", "robot", "tracking", "scripts"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path == ROOT / "app" / "jsonable.py":
                continue
            for node in ast.parse(path.read_text()).body:  # module-level functions
                if isinstance(node, ast.FunctionDef) and node.name in names:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
    assert found == []


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (None, "file not found"),
        (b"{ not json", "not a JSON file"),
        (b"\xff\xfe", "not a JSON file"),
    ],
)
def test_read_json_says_in_one_line_what_is_wrong_with_the_file(
    tmp_path: Path, content: bytes | None, needle: str
) -> None:
    path = tmp_path / "best.json"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_json(path, "--config")
    message = str(info.value)
    assert message.startswith(f"--config {path}: {needle}"), message
    assert "\n" not in message


def test_read_json_reads_what_json_reads(tmp_path: Path) -> None:
    path = tmp_path / "ok.json"
    path.write_text('{"a": [1, 2.5, null]}', encoding="utf-8")
    assert read_json(path) == {"a": [1, 2.5, None]}
