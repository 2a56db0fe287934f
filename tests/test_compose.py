"""Composition (app/compose): the command line parses once and hands the parsed values
down, and outputs are plug-ins.

Parse once: the robot's description, the loop configuration and the mode are each read once
on their way from the command line to a built loop (before: `--robot` was read by the check
and again by the composition, the loop configuration was built to be checked, thrown away
and built again from the arbitration's dict, and the loop's arbiter parsed its parsed mode
again).

Outputs: an output defined and registered here, in a test file, reaches every consumer
without an edit to them: `run`'s and `serve`'s options, the checked settings (a bad value
one line and exit 2), the composition (opened with the task, the scene exported for it, the
camera's frames recorded for it), the loop (every tick, each session's start and stop, each
recorded episode), `run`'s summary line and the close.

Sources: a hand input that is not a camera, defined and registered here, reaches every
consumer likewise: the `--source` grammar of `run` and `serve` (and their help), its checks
(no target where it takes none; no video to record from it), the composition (opened with
the task and the robot's start, its hand driving the loop, its world's defaults applied),
`run` (headless unless live), the session's metadata and the page's label of it.
"""

from __future__ import annotations

import argparse
import importlib
import json
import threading
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from dsteleop.app import outputs, sources
from dsteleop.app.cli import serve
from dsteleop.app.cli.main import COMMANDS, main
from dsteleop.app.cli.options import add_loop_options, loop_options
from dsteleop.app.compose import LoopOptions, build
from dsteleop.app.compose.options import RobotSpec
from dsteleop.app.loop import LoopConfig
from dsteleop.app.outpaths import output_file
from dsteleop.app.outputs import OutputBase, OutputContext, OutputKind
from dsteleop.app.session.episodes import Episode
from dsteleop.app.session.reader import read_session
from dsteleop.app.session.schema import TickRecord
from dsteleop.app.sources import Defaults, Opened, SourceContext, SourceKind
from dsteleop.app.viewer.panel import source_label
from dsteleop.arbitration import Mode
from dsteleop.errors import ConfigError
from dsteleop.robot import description
from dsteleop.tracking.sources import SourceSpec
from tests.fakes import ScriptedHand


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


# --- an output of this file: a tally of what it was told, written at close -----------------


class Tally(OutputBase):
    """Counts the ticks, sessions and episodes it hears of; writes them to its file at close."""

    def __init__(self, path: Path, ctx: OutputContext) -> None:
        self.path = path
        self.frames = ctx.frames
        self.ticks = 0
        self.sessions: list[str] = []
        self.stopped = 0
        self.episodes: list[tuple[str, int, int]] = []
        self.threads: set[str] = set()
        self.has_poses = False

    def observe(self, record: TickRecord) -> None:
        self.ticks += 1
        self.has_poses = record.plant.scene is not None

    def start_session(self, folder: Path) -> None:
        self.sessions.append(str(folder))

    def stop_session(self) -> None:
        self.stopped += 1

    def episode(
        self, folder: Path, meta: dict[str, Any], episode: Episode, ticks: tuple[TickRecord, ...]
    ) -> None:
        self.episodes.append((episode.end, episode.first, len(ticks)))
        self.threads.add(threading.current_thread().name)

    def summary(self) -> dict[str, Any]:
        return {"file": str(self.path), "ticks": self.ticks}

    def close(self) -> None:
        self.path.write_text(
            json.dumps({**self.__dict__, "path": str(self.path), "threads": sorted(self.threads)})
        )


def _add_tally(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tally", type=output_file, default=None, metavar="FILE.json")


def _parse_tally(args: argparse.Namespace, source: Any) -> Path | None:
    if args.tally is None:
        return None
    if args.tally.suffix != ".json":
        raise ConfigError(f"--tally: expected a .json file, got {args.tally}")
    return Path(args.tally)


TALLY = OutputKind(
    "tally",
    _add_tally,
    _parse_tally,
    Tally,
    wants_frames=True,
    wants_scene=True,
    sessions=lambda path: Path(path).parent / "tally-sessions",
)


def _parser(command: str) -> argparse.ArgumentParser:
    """A command's parser, with the options its module adds (as `main` builds it)."""
    parser = argparse.ArgumentParser()
    importlib.import_module(COMMANDS[command][0]).add_arguments(parser)
    return parser


@pytest.fixture
def tally() -> Iterator[OutputKind[Path]]:
    kind = outputs.register(TALLY)
    try:
        yield kind
    finally:
        outputs.unregister(kind)


def test_an_output_from_a_test_file_is_everywhere(tally: OutputKind[Path], tmp_path: Path) -> None:
    assert outputs.kind("tally") is tally and tally in outputs.registered()
    for command in ("run", "serve"):
        parsed = _parser(command).parse_args(["--tally", str(tmp_path / "t.json")])
        assert parsed.tally == tmp_path / "t.json"
    args = _parser("serve").parse_args(["--source", "video:clip.mp4", "--tally", "t.json"])
    options = serve.command(args).options
    # Read and checked, and the camera's frames recorded for it (the source has pixels).
    assert options.outputs == {"tally": Path("t.json"), outputs.FRAMES: True}
    assert outputs.session_root(options.outputs) == Path("tally-sessions")


def test_a_run_feeds_a_new_output_every_tick_session_and_episode(
    tally: OutputKind[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "t.json"
    assert main(["run", "--source", "demo", "--tally", str(out), "--max-seconds", "2"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    told = json.loads(out.read_text())  # written at close
    assert summary["tally"] == {"file": str(out), "ticks": summary["ticks"]}
    assert told["ticks"] == summary["ticks"] == 60
    # It needs sessions: one was recorded from the start, under its folder.
    (session,) = told["sessions"]
    assert Path(session).parent == tmp_path / "tally-sessions" == Path(summary["session"]).parent
    assert told["stopped"] == 1
    # The episode the run ended ("stopped" at --max-seconds), with its ticks, on the
    # recorder's thread; as the session holds it.
    recorded = read_session(Path(session))
    assert told["episodes"] == [["stopped", 0, 60]] and told["threads"] == ["dsteleop-recorder"]
    assert [e.end for e in recorded.episodes] == ["stopped"]
    # The scene's poses were exported for it; the demo has no frames to record.
    assert told["has_poses"] is True and told["frames"] is False


def test_a_bad_value_of_a_new_output_is_one_line_and_exit_2(
    tally: OutputKind[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--source", "demo", "--tally", str(tmp_path / "t.txt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"dsteleop run: error: --tally: expected a .json file, got {tmp_path / 't.txt'}"]


def test_an_unknown_or_twice_registered_output_is_a_config_error(tally: OutputKind[Path]) -> None:
    with pytest.raises(ConfigError, match="unknown output 'nope'"):
        outputs.kind("nope")
    with pytest.raises(ConfigError, match="registered already"):
        outputs.register(TALLY)


# --- a source of this file: a hand of its own, held where the robot starts ------------------


class StillHand(ScriptedHand):
    """A hand that is no camera: it holds the robot's start pose (through its own delay)."""

    def describe(self) -> str:
        return "a still hand (test)"


def _open_still(spec: SourceSpec, ctx: SourceContext) -> Opened:
    start = ctx.X_start
    return Opened(hand=StillHand(lambda t: start, input_delay_s=ctx.input_delay_s))


STILL = SourceKind(
    "still",
    "still",
    _open_still,
    label=lambda spec: "still hand",
    defaults=lambda seed: Defaults(goal_noise_m=0.0, input_delay_s=0.05),
)


@pytest.fixture
def still() -> Iterator[SourceKind]:
    kind = sources.register(STILL)
    try:
        yield kind
    finally:
        sources.unregister(kind)


def test_a_source_from_a_test_file_is_everywhere(still: SourceKind) -> None:
    assert sources.kind("still") is still and sources.parse(" still ") == SourceSpec("still")
    assert "or still" in sources.grammar()
    for command in ("run", "serve"):
        parser = _parser(command)
        assert "still" in parser.format_help()
        assert loop_options(parser.parse_args(["--source", "still"])).source.kind == "still"
    assert source_label(SourceSpec("still")) == "still hand"
    with pytest.raises(ConfigError, match="takes no target"):
        sources.parse("still:x")


def test_a_run_is_driven_by_a_new_source(
    still: SourceKind, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["run", "--source", "still", "--max-seconds", "1", "--record", str(tmp_path / "s")]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["source"] == "still" and summary["ticks"] == 30
    assert summary["timing"]["headless"] is True  # not live: run on the manual clock
    session = read_session(tmp_path / "s")
    assert (
        session.meta["source_kind"] == "still" and session.meta["source"] == "a still hand (test)"
    )
    # Its world's defaults, where the command line said nothing.
    assert session.meta["loop"]["input_delay_s"] == 0.05
    assert session.meta["plant"]["goal_noise_m"] == 0.0
    # The hand was seen (after its delay) and held still: the robot stayed near its start.
    held = [r for r in session.records if r.hand is not None and r.hand.X_human is not None]
    assert len(held) >= 25


def test_a_source_without_pixels_records_no_video(
    still: SourceKind, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["run", "--source", "still", "--record-video"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--record-video: --source still has no camera frames" in err[0]
