"""Composition (app/compose): the command line parses once and hands the parsed values
down. The robot's description, the loop configuration and the mode are each read once on
their way from the command line to a built loop (before: `--robot` was read by the check
and again by the composition, the loop configuration was built to be checked, thrown away
and built again from the arbitration's dict, and the loop's arbiter parsed its parsed mode
again)."""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from dsteleop.app.cli.options import add_loop_options, loop_options
from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.compose.options import RobotSpec
from dsteleop.app.loop import LoopConfig
from dsteleop.arbitration import Mode
from dsteleop.robot import description


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_loop_options(parser, "demo", "record")
    return parser.parse_args(["--source", "demo", *argv])


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> Iterator[Counter[str]]:
    """Counts every read of a robot description, loop configuration and mode name."""
    counts: Counter[str] = Counter()

    def counted(name: str, real: Any) -> Any:
        def wrapper(*args: Any, **kw: Any) -> Any:
            counts[name] += 1
            return real(*args, **kw)

        return wrapper

    monkeypatch.setattr(description, "_from_text", counted("robot", description._from_text))
    from_dict = LoopConfig.from_dict.__func__  # type: ignore[attr-defined]
    monkeypatch.setattr(LoopConfig, "from_dict", classmethod(counted("loop", from_dict)))
    parse = Mode.parse.__func__  # type: ignore[attr-defined]
    monkeypatch.setattr(Mode, "parse", classmethod(counted("mode", parse)))
    yield counts


def test_each_choice_is_read_once_from_the_command_line_to_a_built_loop(
    reads: Counter[str], tmp_path: Path
) -> None:
    config = tmp_path / "c.json"
    config.write_text('{"arbitration": {"kappa": 7}, "loop": {"input_delay_s": 0.1}}')
    options = loop_options(_parse("--robot", "panda", "--mode", "S", "--config", str(config)))
    assert isinstance(options.robot, RobotSpec) and options.robot.description.name == "panda"
    assert options.loop.mode is Mode.S and options.loop.arbitration.kappa == 7
    assert options.input_delay_given
    built = build(options, realtime=False)
    try:
        assert built.loop.robot.name == "panda" and built.loop.arbiter.mode is Mode.S
        assert built.loop.config.input_delay_s == 0.1
    finally:
        built.close()
    assert reads == Counter(robot=1, loop=1, mode=1)


def test_a_robot_spec_says_what_it_is() -> None:
    spec = RobotSpec.parse("iiwa")
    assert str(spec) == spec.description.name and not spec.linked and spec.link is None
    assert LoopOptions.of("demo").robot.description.name == spec.description.name
