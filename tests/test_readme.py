"""The README is a guide a newcomer reads in minutes, and every command in it runs as written.

What is checked (issue 23, item 6):

- Size under 12 KB, and no table cell over 200 characters (per-area detail lives in `docs/`,
  measurement history in git).
- It opens with the two commands for a fresh machine, `./dev.sh start` and `./dev.sh test`;
  they set up and then serve forever or run the whole suite (minutes), so they are checked
  to be commands `dev.sh` has, not run.
- **The short commands run.** A short command is a line of a fenced code block that starts
  with `dsteleop`: the README keeps there only commands that need no data outside the
  repository and end within a minute or two on a 2-core machine (help, the demo to its first
  outcome). Each runs as written in a fresh non-interactive `bash` in the repository, with
  the virtualenv's `bin` first on `PATH` (as the README says to set up), and must exit 0 with
  the output its shape promises: help text naming the subcommands, or one JSON line with an
  outcome.
- **The templates are real.** The commands in the tables carry placeholders (`DIR`, `N`), so
  they are not run; instead every `--option` they name must appear in the `--help` of the
  subcommand they name, and the loop options in the `run --help`.
- Every relative link and image points to a file that exists.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
BIN = Path(sys.executable).parent  # the virtualenv's bin, where `dsteleop` is installed
MAX_BYTES = 12_000
MAX_CELL = 200
SUBCOMMANDS = (
    "serve",
    "run",
    "replay",
    "export",
    "robot",
    "robot-sim",
    "sim",
    "tune",
    "track",
    "bench",
)


def _text() -> str:
    return README.read_text(encoding="utf-8")


def _fenced_lines(text: str) -> list[str]:
    blocks = re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)
    return [ln.strip() for b in blocks for ln in b.splitlines() if ln.strip()]


def _short_commands(text: str) -> list[str]:
    return [ln for ln in _fenced_lines(text) if ln.split()[0] == "dsteleop"]


def _table_cells(text: str) -> list[str]:
    cells = []
    for line in text.splitlines():
        if line.startswith("|") and not re.fullmatch(r"\|[-| :]+\|", line):
            cells += [c.strip() for c in re.split(r"(?<!\\)\|", line.strip("|"))]
    return cells


def _shell(command: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(
        ["bash", "-c", command],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )


@cache
def _help(sub: str) -> str:
    r = _shell(f"dsteleop {sub} --help", 120)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout


def test_readme_is_short_and_its_tables_are_narrow() -> None:
    size = len(README.read_bytes())
    assert size < MAX_BYTES, f"README.md is {size} bytes (limit {MAX_BYTES})"
    long = [c for c in _table_cells(_text()) if len(c) > MAX_CELL]
    assert not long, [c[:80] + "..." for c in long]


def test_readme_opens_with_the_two_commands_dev_sh_has() -> None:
    first = _fenced_lines(_text())[:2]
    assert [ln.split("#")[0].strip() for ln in first] == ["./dev.sh start", "./dev.sh test"]
    script = (REPO / "dev.sh").read_text(encoding="utf-8")
    for sub in ("start", "test"):
        assert re.search(rf"^\s*{sub}\)", script, flags=re.M), f"dev.sh has no {sub!r}"


def test_readme_links_point_to_files_that_exist() -> None:
    links = re.findall(r"\]\(([^)\s]+)\)", _text())
    local = [t.split("#")[0] for t in links if not re.match(r"[a-z]+://", t)]
    assert local, "no links found"
    missing = [t for t in local if t and not (REPO / t).exists()]
    assert not missing, missing


def test_the_commands_in_the_tables_name_options_their_subcommand_has() -> None:
    text = _text()
    templates = re.findall(r"`(dsteleop [^`]+)`", text)
    assert len(templates) >= len(SUBCOMMANDS)
    for command in templates:
        sub = command.split()[1]
        if sub.startswith("-"):
            continue
        assert sub in SUBCOMMANDS, command
        for option in re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", command):
            assert option in _help(sub), f"{option} of {command!r} not in `dsteleop {sub} --help`"
    loop = text[text.index("LOOP OPTIONS, ") :].split("\n\n")[0]
    for option in set(re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", loop)):
        assert option in _help("run") and option in _help("serve"), option


def _check_output(command: str, out: str) -> None:
    """The shape the README promises for each kind of short command."""
    words = command.split()
    if "--help" in words or words == ["dsteleop"]:
        assert out.startswith("usage: dsteleop"), out[:200]
        if len(words) == 2:  # the top-level help names every subcommand
            assert all(s in out for s in SUBCOMMANDS), out
        return
    if words[1] == "run":
        result = json.loads(out.strip().splitlines()[-1])
        assert result["outcome"] in ("success", "failure"), result
        assert result["source"] == "demo" and result["stopped_by"] == "outcome", result
        return
    raise AssertionError(f"no expected output shape for {command!r}: add one here")


def test_readme_has_short_commands_to_run() -> None:
    commands = _short_commands(_text())
    assert "dsteleop --help" in commands
    assert any(c.startswith("dsteleop run --source demo") for c in commands), commands


@pytest.mark.slow
@pytest.mark.parametrize("command", _short_commands(README.read_text(encoding="utf-8")))
def test_short_command_runs_as_written(command: str) -> None:
    r = _shell(command, timeout_s=300)
    assert r.returncode == 0, (command, r.stderr[-2000:])
    _check_output(command, r.stdout)
