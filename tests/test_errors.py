"""The project's error family (dsteleop/errors.py) is the only thing validators and input checks
raise: a bad setting is a ConfigError, bad data a FormatError or another InputError, a caller's
bug a ContractError; the command turns the first three into one line and exit code 2."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import dsteleop
from dsteleop.errors import (
    ConfigError,
    ContractError,
    DsteleopError,
    FormatError,
    InputError,
)

PACKAGE = Path(dsteleop.__file__).resolve().parent
#: The folders scanned: the package's four, and the repository's scripts (they validate their
#: inputs too: scripts/tune_sweep.py's merge of best.json files).
SOURCES = (
    *(PACKAGE / d for d in ("app", "arbitration", "robot", "tracking")),
    PACKAGE.parent / "scripts",
)


def _bare_value_errors(path: Path) -> list[int]:
    """Lines of `path` that raise ValueError itself (not one of the family's subclasses)."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Raise) or node.exc is None:
            continue
        exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
        if isinstance(exc, ast.Name) and exc.id == "ValueError":
            lines.append(node.lineno)
    return sorted(lines)


def test_no_module_raises_a_bare_value_error() -> None:
    files = [p for d in SOURCES for p in sorted(d.resolve().rglob("*.py"))]
    assert len(files) > 100  # the scan reads the package, not an empty folder
    assert any(p.parent.name == "scripts" for p in files)  # and the scripts
    bare = {
        str(p.relative_to(PACKAGE.parent)): lines for p in files if (lines := _bare_value_errors(p))
    }
    assert bare == {}, f"raise ConfigError, FormatError or ContractError instead: {bare}"


def test_the_scan_finds_a_bare_value_error(tmp_path: Path) -> None:
    f = tmp_path / "m.py"
    f.write_text(
        "def f(x):\n    if x:\n        raise ValueError('x')\n    raise ValueError\n"
        "def g():\n    raise ConfigError('y')\n"
    )
    assert _bare_value_errors(f) == [3, 4]


def test_the_family_keeps_value_error_for_old_callers() -> None:
    """Readers catch ValueError to add the file and line: the data and setting errors stay
    ValueErrors, a caller's bug is not a DsteleopError (it keeps its traceback)."""
    assert issubclass(ConfigError, ValueError) and issubclass(ConfigError, DsteleopError)
    assert issubclass(FormatError, ValueError) and issubclass(FormatError, InputError)
    assert issubclass(ContractError, ValueError)
    assert not issubclass(ContractError, DsteleopError)


def test_validators_raise_the_family() -> None:
    """One of each kind, from modules that raised a bare ValueError before."""
    from dsteleop.app.loop.timing import RateClock
    from dsteleop.arbitration.history import OperatorHistory
    from dsteleop.arbitration.metrics import t_test
    from dsteleop.tracking.filters import OneEuroConfig

    with pytest.raises(ConfigError, match="min_cutoff_hz"):
        OneEuroConfig(min_cutoff_hz=0.0, beta=0.1)
    with pytest.raises(ConfigError, match="rate_hz"):
        RateClock(rate_hz=0.0)
    with pytest.raises(FormatError, match="not an operator history"):
        OperatorHistory.from_dict({"schema": "other"})
    with pytest.raises(ContractError, match="two samples"):
        t_test([1.0], [2.0, 3.0])


def test_a_setting_error_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """A validator's ConfigError, raised inside a command, reaches the user as one line."""
    from dsteleop.app.cli.main import main

    rc = main(["run", "--source", "demo", "--rate", "0"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "Traceback" not in err
    assert len([line for line in err.splitlines() if line.strip()]) == 1
