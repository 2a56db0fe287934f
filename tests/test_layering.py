"""The layers, read from the source with `ast` (every import, also those inside functions
and under TYPE_CHECKING): arrows point down only (docs/ARCHITECTURE.md, "Layers").

    app/cli/             the command line: parses, then hands a typed value down
    app/... (the rest)   composition (app/compose), the loop, sessions, outputs, the study
    robot/, tracking/    the robot and the hand
    arbitration/         the method: imports none of the above

A rule is a package and the packages it must not import, with the reason. A test of this
file also proves that a rule can fail: a module that breaks one is caught.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The source folders and the package each installs as (pyproject.toml's package-dir).
FOLDERS = {
    "app": "dsteleop.app",
    "arbitration": "dsteleop.arbitration",
    "tracking": "dsteleop.tracking",
    "robot": "dsteleop.robot",
}


@dataclass(frozen=True)
class Rule:
    """Modules under `package` (but not under `except_under`) import nothing under any of
    `forbidden`."""

    package: str
    forbidden: tuple[str, ...]
    why: str
    except_under: tuple[str, ...] = ()


RULES = (
    Rule(
        "dsteleop.app",
        ("dsteleop.app.cli",),
        "the command line is the top layer: it parses and hands a typed value down "
        "(app/compose builds the loop); nothing below imports a command",
        except_under=("dsteleop.app.cli",),
    ),
    Rule(
        "dsteleop.arbitration",
        ("dsteleop.app", "dsteleop.tracking", "dsteleop.robot"),
        "the method is pure: no I/O, no robot, no camera",
    ),
    Rule("dsteleop.tracking", ("dsteleop.app", "dsteleop.robot"), "the hand knows no robot"),
    Rule("dsteleop.robot", ("dsteleop.app",), "a robot knows no loop, session or command"),
)


def module_name(path: Path) -> str:
    """The dotted name of a source file (`app/cli/run.py` -> `dsteleop.app.cli.run`)."""
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [FOLDERS[rel.parts[0]], *rel.parts[1:]]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(source: str, module: str, is_package: bool) -> Iterator[tuple[int, str]]:
    """(line, imported module) of every import in `source`, relative ones resolved; for
    `from X import a`, both `X` and `X.a` (a may be a module)."""
    base = module.split(".") if is_package else module.split(".")[:-1]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                up = base[: len(base) - (node.level - 1)]
                target = ".".join([*up, *([node.module] if node.module else [])])
            else:
                target = node.module or ""
            yield node.lineno, target
            for alias in node.names:
                yield node.lineno, f"{target}.{alias.name}"


def under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def violations(module: str, source: str, is_package: bool = False) -> list[str]:
    """Every import of `module` (its `source`) that a rule forbids, as one line each."""
    out = []
    for rule in RULES:
        if not under(module, rule.package) or any(under(module, e) for e in rule.except_under):
            continue
        for line, name in imports(source, module, is_package):
            bad = next((f for f in rule.forbidden if under(name, f)), None)
            if bad is not None:
                out.append(f"{module}:{line} imports {name} ({bad}: {rule.why})")
    return sorted(set(out))


def sources() -> Iterator[Path]:
    for folder in FOLDERS:
        yield from sorted((ROOT / folder).rglob("*.py"))


def test_every_layer_imports_only_below_it() -> None:
    found = [
        v
        for path in sources()
        for v in violations(
            module_name(path), path.read_text(encoding="utf-8"), path.name == "__init__.py"
        )
    ]
    assert not found, "\n".join(found)


def test_the_sources_are_read() -> None:
    names = {module_name(p) for p in sources()}
    assert {"dsteleop.app.cli.run", "dsteleop.app.compose.root", "dsteleop.arbitration"} <= names
    assert len(names) > 100


@pytest.mark.parametrize(
    ("module", "source"),
    [
        ("dsteleop.app.bench.loop", "def f():\n    from dsteleop.app.cli.options import x\n"),
        ("dsteleop.app.study.run", "import dsteleop.app.cli.main\n"),
        ("dsteleop.app.study.run", "from dsteleop.app import cli\n"),
        ("dsteleop.app.study.run", "from ..cli import progress\n"),
        ("dsteleop.arbitration.metrics", "from dsteleop.app.ports import Robot\n"),
        ("dsteleop.robot.world", "if TYPE_CHECKING:\n    from dsteleop.app.loop import L\n"),
    ],
)
def test_a_module_that_breaks_a_rule_is_caught(module: str, source: str) -> None:
    assert violations(module, source)


def test_the_command_line_may_import_everything() -> None:
    assert not violations("dsteleop.app.cli.run", "from dsteleop.app.cli.options import x\n")
    assert not violations("dsteleop.app.compose.root", "from dsteleop.app.loop import T\n")
