"""Options that surprised a new user (issue 34, "Crashes and surprises"), each now either
working as its help says or refused in one line (exit code 2) that says why.

Before: `run --reset-after S` was accepted and did nothing (run stops at its first outcome);
`bench --only a,b` was refused though the help says "these groups"; a bad robot name in a
link file was blamed on `--robot`; recordings/README.md said serve records under
`./sessions/` by default.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dsteleop.app.bench import GROUPS
from dsteleop.app.cli import serve
from dsteleop.app.cli.bench import groups
from dsteleop.app.cli.main import main
from dsteleop.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]


def _error_line(capsys: pytest.CaptureFixture[str]) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    assert captured.out == "", "the command ran: " + captured.out[:200]
    return lines[0]


def test_run_refuses_reset_after_and_says_why(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--source", "demo", "--reset-after", "2"]) == 2
    line = _error_line(capsys)
    assert line.startswith("dsteleop run: error: --reset-after 2: run stops at its first outcome")
    assert "serve" in line
    # The same from a --config file's loop section, named as such.
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"arbitration": {}, "loop": {"reset_after_s": 3}}))
    assert main(["run", "--source", "demo", "--config", str(config)]) == 2
    assert f"--config {config}: reset_after_s 3" in _error_line(capsys)


def test_run_takes_reset_after_0_its_own_value(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["run", "--source", "demo", "--reset-after", "0", "--max-seconds", "0.5"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["stopped_by"] == "max-seconds" and summary["ticks"] == 15


def test_bench_only_takes_a_comma_list_and_repeats() -> None:
    assert groups(None) == list(GROUPS)
    assert groups(["arbitration,robot"]) == ["arbitration", "robot"]
    assert groups(["robot", "arbitration, robot", "loop"]) == ["robot", "arbitration", "loop"]
    with pytest.raises(ConfigError, match="unknown bench group 'nosuch'"):
        groups(["robot,nosuch"])
    with pytest.raises(ConfigError, match="names no group"):
        groups([","])


def test_bench_only_with_an_unknown_group_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--only", "arbitration,nosuch"]) == 2
    line = _error_line(capsys)
    assert line.startswith("dsteleop bench: error: unknown bench group 'nosuch'"), line


@pytest.mark.slow
def test_bench_only_runs_each_group_of_a_comma_list() -> None:
    r = subprocess.run(
        [*CLI, "bench", "--only", "arbitration,robot", "--quick"],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert "ds_step_us" in out  # the arbitration group's
    assert "robot_tick_ms" in out  # the robot group's


@pytest.mark.parametrize(
    ("robot", "reason"),
    [
        ('"nosuch"', "unknown robot 'nosuch'"),
        ('"gone.toml"', "no such robot description file"),
    ],
)
def test_a_bad_robot_in_a_link_file_names_the_file_and_its_field(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], robot: str, reason: str
) -> None:
    link = tmp_path / "link.json"
    link.write_text('{"robot": ' + robot + "}")
    for argv in (
        ["run", "--source", "demo", "--robot", f"zenoh:{link}"],
        ["robot-sim", "--zenoh", str(link)],
    ):
        assert main(argv) == 2
        line = _error_line(capsys)
        assert f"link config {link}: field robot: {reason}" in line, line
        assert "--robot:" not in line, line
    # --robot itself is still named when it is the one that is wrong.
    assert main(["run", "--source", "demo", "--robot", "nosuch"]) == 2
    assert "--robot: unknown robot 'nosuch'" in _error_line(capsys)


def test_recordings_readme_says_where_serve_records_by_default(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    text = " ".join((REPO / "recordings" / "README.md").read_text(encoding="utf-8").split())
    assert "./sessions/" not in text
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert serve.default_record_root() == tmp_path / "data" / "dsteleop" / "sessions"
    assert "`$XDG_DATA_HOME/dsteleop/sessions/`" in text
    monkeypatch.delenv("XDG_DATA_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert serve.default_record_root() == tmp_path / "home" / ".local/share/dsteleop/sessions"
    assert "`~/.local/share/dsteleop/sessions/`" in text
