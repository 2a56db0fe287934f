"""The session schema (the typed tick record and its JSON form), the schema-1 reader, the
`--config`/`--param` options of `run` and `sim`, and the `--source` grammar."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from dsteleop.app.cli.main import main
from dsteleop.app.ports import NO_HAND, HumanInput, PlantStep
from dsteleop.app.session.reader import read_session
from dsteleop.app.session.schema import (
    SCHEMA,
    BeliefRecord,
    Status,
    TickRecord,
    decode,
    decode_event,
    encode,
    encode_event,
)
from dsteleop.app.session.writer import META, TICKS, Recorder, SessionWriter
from dsteleop.app.sources import parse as parse_source
from dsteleop.arbitration import STEP_ARRAYS, ArbitrationStep, HandState, Mode, dim_names
from dsteleop.errors import ConfigError, InputError
from dsteleop.robot.task import EventKind, Outcome, Phase, TaskEvent
from dsteleop.tracking.sources import SourceSpec
from dsteleop.tracking.types import HandSample

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]
RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"
SCHEMA1 = Path(__file__).resolve().parent / "golden" / "schema1-demo-DS-spoon"
DIMS = dim_names(("thumb", "index", "middle", "ring"))
Array = NDArray[np.float64]


# --- the tick record and its JSON form ------------------------------------------------------


def _state(rng: np.random.Generator, F: int = 4) -> HandState:
    return HandState.from_rotvec(rng.normal(size=3), rng.normal(size=3), rng.uniform(size=F))


def _sample(rng: np.random.Generator, seq: int, t: float) -> HandSample:
    return HandSample(
        seq=seq,
        t_capture_s=t,
        t_tracked_s=t + 0.012,
        detected=True,
        handedness="Right",
        score=0.9731,
        landmarks_image=rng.uniform(size=(21, 3)),
        landmarks_world=rng.normal(scale=0.05, size=(21, 3)),
        p_cam_palm_m=rng.normal(size=3),
        R_cam_palm=_state(rng).rotation,
        openness=rng.uniform(size=5),
        raw_p_cam_palm_m=rng.normal(size=3),
        raw_R_cam_palm=_state(rng).rotation,
        raw_openness=rng.uniform(size=5),
        width_px=640,
        height_px=480,
    )


def full_record(seed: int = 0) -> TickRecord:
    """A tick with every field set: a tracked hand, an arbitration, events and an outcome."""
    rng = np.random.default_rng(seed)
    t = 17.4 + rng.uniform()
    D = len(DIMS)
    X_next = _state(rng)
    step = ArbitrationStep(
        **{k: rng.normal(size=D) for k in STEP_ARRAYS},
        X_next=X_next,
    )
    hand = HumanInput(
        seq=523,
        t_capture_s=t - 0.05,
        t_tracked_s=t - 0.03,
        X_human=_state(rng),
        reason="",
        sample=_sample(rng, 523, t - 0.05),
    )
    plant = PlantStep(
        X_current=_state(rng),
        phase=Phase.DONE,
        events=(TaskEvent(EventKind.RELEASE, t), TaskEvent(EventKind.SUCCESS, t, "in_bin")),
        outcome=Outcome(True, "in_bin", 17.25, "spoon"),
    )
    return TickRecord(
        k=525,
        t_s=t,
        mode=Mode.S,
        dims=DIMS,
        status=Status.TRACKING,
        reason="",
        hand=hand,
        step=step,
        X_goal=_state(rng),
        X_next=X_next,
        U_cmd=rng.normal(size=D),
        plant=plant,
        X_human=_state(rng),
        notes=("mode:S", 'params:{"kappa": 8.0}', "calibrate"),
        timing={"rate_hz": 30.0, "jitter_ms": 0.125, "tick_ms": 2.5, "overruns": 0.0},
        X_reset=_state(rng),
        belief=BeliefRecord(
            ("spoon", "spatula", "ladle"),
            np.array([0.01, 0.2345678901234, 0.7554321098766]),
            2,
            rng.uniform(size=D),
            float(rng.uniform()),
        ),
    )


def lost_record() -> TickRecord:
    """A tick without a hand: no arbitration, no goal, no events, nothing optional."""
    rng = np.random.default_rng(7)
    X = _state(rng)
    return TickRecord(
        k=3,
        t_s=0.1,
        mode=Mode.DS,
        dims=DIMS,
        status=Status.LOST,
        reason=NO_HAND,
        hand=None,
        step=None,
        X_goal=None,
        X_next=X,
        U_cmd=np.zeros(len(DIMS)),
        plant=PlantStep(X_current=X, phase=Phase.PICK),
    )


def through_json(r: TickRecord) -> TickRecord:
    return decode(json.loads(json.dumps(encode(r), allow_nan=False)), r.dims)


def assert_states_equal(a: HandState | None, b: HandState | None, rtol: float = 0.0) -> None:
    assert (a is None) == (b is None)
    if a is None or b is None:
        return
    for name in ("position", "rotation", "openness"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=rtol, atol=0)


def assert_round_trip(r: TickRecord, back: TickRecord) -> None:
    """`back` holds the values of `r`: the inputs of a replay exactly, the outputs to the 10
    significant digits the record keeps, the landmarks to 4 decimals."""
    assert (back.k, back.t_s, back.mode, back.dims) == (r.k, r.t_s, r.mode, r.dims)
    assert (back.status, back.reason, back.notes) == (r.status, r.reason, r.notes)
    assert back.plant.phase is r.plant.phase
    assert back.plant.events == r.plant.events
    assert back.outcome == r.outcome
    assert_states_equal(back.X_current, r.X_current)
    assert_states_equal(back.X_goal, r.X_goal)
    assert_states_equal(back.X_human, r.X_human)
    assert_states_equal(back.X_reset, r.X_reset)
    assert_states_equal(back.X_next, r.X_next, rtol=1e-9)
    np.testing.assert_allclose(back.U_cmd, r.U_cmd, rtol=1e-9, atol=0)
    assert dict(back.timing) == dict(r.timing)
    assert (back.belief is None) == (r.belief is None)
    if r.belief is not None and back.belief is not None:
        b, a = r.belief, back.belief
        assert (a.names, a.map_index, a.map_name) == (b.names, b.map_index, b.map_name)
        np.testing.assert_allclose(a.probability, b.probability, rtol=1e-9, atol=0)
        np.testing.assert_allclose(a.confidence, b.confidence, rtol=1e-9, atol=0)
        assert a.confidence_joint == pytest.approx(b.confidence_joint, rel=1e-9)
    assert (back.step is None) == (r.step is None)
    if r.step is not None and back.step is not None:
        for k in STEP_ARRAYS:
            np.testing.assert_allclose(getattr(back.step, k), getattr(r.step, k), rtol=1e-9)
        assert_states_equal(back.step.X_next, r.X_next, rtol=1e-9)
    assert (back.hand is None) == (r.hand is None)
    if r.hand is None or back.hand is None:
        return
    h, g = r.hand, back.hand
    assert (g.seq, g.t_capture_s, g.t_tracked_s, g.reason) == (
        h.seq,
        h.t_capture_s,
        h.t_tracked_s,
        h.reason,
    )
    assert_states_equal(g.X_human, h.X_human)
    assert (g.sample is None) == (h.sample is None)
    if h.sample is None or g.sample is None:
        return
    s, q = h.sample, g.sample
    assert (q.detected, q.handedness, q.score) == (s.detected, s.handedness, s.score)
    assert (q.width_px, q.height_px) == (s.width_px, s.height_px)
    assert s.landmarks_image is not None and s.landmarks_world is not None
    assert q.landmarks_image is not None and q.landmarks_world is not None
    np.testing.assert_array_equal(q.landmarks_image, np.round(s.landmarks_image, 4))
    np.testing.assert_array_equal(q.landmarks_world, np.round(s.landmarks_world, 4))
    np.testing.assert_array_equal(q.p_cam_palm_m, s.p_cam_palm_m)
    np.testing.assert_array_equal(q.R_cam_palm, s.R_cam_palm)
    np.testing.assert_array_equal(q.openness, s.openness)
    # Not recorded: the unfiltered values (NaN when read back) and the pixels.
    assert np.isnan(q.raw_p_cam_palm_m).all() and q.image is None


@pytest.mark.parametrize("make", [full_record, lost_record])
def test_a_tick_record_round_trips_through_json(make: Any) -> None:
    r = make()
    back = through_json(r)
    assert_round_trip(r, back)
    # The JSON form is a fixed point: what is read back encodes to the same object.
    assert encode(back) == encode(r)
    assert encode(through_json(back)) == encode(r)


def test_a_tick_record_round_trips_through_a_session_folder(tmp_path: Path) -> None:
    records = [lost_record(), full_record(1), full_record(2)]
    rec = Recorder(SessionWriter(tmp_path / "s", {"mode": "S", "dims": list(DIMS)}))
    for r in records:
        rec.put(r)
    rec.close({"outcome": "success"})
    s = read_session(tmp_path / "s")
    assert s.meta["schema"] == SCHEMA and s.complete and not s.truncated
    assert s.dims == DIMS and s.mode is Mode.S and len(s.records) == 3
    for r, back in zip(records, s.records):
        assert_round_trip(r, back)
    # Version 2 keeps task events and operator notes apart, and the outcome as an object.
    line = json.loads((tmp_path / "s" / TICKS).read_text().splitlines()[1])
    assert line["events"] == ["release", "success:in_bin"]
    assert line["notes"] == ["mode:S", 'params:{"kappa": 8.0}', "calibrate"]
    assert line["outcome"] == {
        "success": True,
        "reason": "in_bin",
        "time_s": 17.25,
        "utensil": "spoon",
    }


def test_a_session_of_schema_4_reads_without_a_belief(tmp_path: Path) -> None:
    """Sessions recorded before the belief (schema 4; a sample session of schema 3 relabelled:
    3 and 4 differ only in the joints, which it has none of) still read: their ticks have
    `belief` None."""
    folder = tmp_path / "old"
    shutil.copytree(RECORDINGS / "demo-DS-spoon", folder)
    meta = json.loads((folder / META).read_text())
    assert meta["schema"] == "dsteleop.session/3"
    meta["schema"] = "dsteleop.session/4"
    (folder / META).write_text(json.dumps(meta))
    s = read_session(folder)
    assert s.records and all(r.belief is None for r in s.records)
    line = json.loads((folder / TICKS).read_text().splitlines()[0])
    assert "belief" not in line


def test_events_encode_and_decode_by_kind() -> None:
    for e in (TaskEvent(EventKind.GRASP, 1.5, "spoon"), TaskEvent(EventKind.RELEASE, 1.5)):
        assert decode_event(encode_event(e), 1.5) == e
    assert encode_event(TaskEvent(EventKind.GOAL, 0.0, "place")) == "goal:place"
    for note in ("mode:S", "reset", "calibrate", 'params:{"kappa": 8.0}'):
        assert decode_event(note, 0.0) is None


# --- schema 1 ---------------------------------------------------------------------------------


def schema1_line(k: int) -> dict[str, Any]:
    """Tick k of the DS sample session (schema 1, recorded by the code before the typed
    record)."""
    with (SCHEMA1 / TICKS).open() as f:
        for line in f:
            d = json.loads(line)
            if d["k"] == k:
                return dict(d)
    raise AssertionError(f"no tick {k}")


def test_a_schema_1_tick_decodes_with_events_and_notes_told_apart() -> None:
    dims = tuple(json.loads((SCHEMA1 / META).read_text())["dims"])
    d = schema1_line(130)
    assert "notes" not in d and d["outcome"] == "" and d["events"] == ["grasp:spoon", "goal:place"]
    # Schema 1 wrote the operator's changes into the same list, ahead of the task's events.
    d["events"] = ["mode:DS", 'params:{"kappa": 8.0}', "calibrate", *d["events"]]
    r = decode(d, dims)
    t = float(d["t"])
    assert r.plant.events == (
        TaskEvent(EventKind.GRASP, t, "spoon"),
        TaskEvent(EventKind.GOAL, t, "place"),
    )
    assert r.plant.segment_changed
    assert r.notes == ("mode:DS", 'params:{"kappa": 8.0}', "calibrate")
    assert r.outcome is None and r.phase is Phase.PLACE and r.mode is Mode.DS
    assert r.status is Status.TRACKING and r.dims == dims
    assert r.step is not None and r.step.alpha.shape == (len(dims),)
    np.testing.assert_array_equal(r.step.alpha, d["arb"]["alpha"])
    np.testing.assert_array_equal(r.X_current.position, d["X_current"][:3])
    assert r.hand is not None and r.hand.sample is not None and r.hand.sample.detected
    # Written again it is a version-2 tick: the two lists apart.
    out = encode(r)
    assert out["events"] == ["grasp:spoon", "goal:place"]
    assert out["notes"] == ["mode:DS", 'params:{"kappa": 8.0}', "calibrate"]
    assert out["outcome"] is None


def test_a_schema_1_outcome_takes_its_reason_from_its_event() -> None:
    dims = tuple(json.loads((SCHEMA1 / META).read_text())["dims"])
    d = schema1_line(525)
    assert d["outcome"] == "success" and d["events"] == ["success:in_bin"]
    r = decode(d, dims)
    assert r.notes == () and r.phase is Phase.DONE
    assert r.outcome is not None and r.outcome.success and r.outcome.reason == "in_bin"
    assert math.isnan(r.outcome.time_s)  # schema 1 did not record it


def test_a_schema_1_tick_rewritten_as_version_2_reads_back(tmp_path: Path) -> None:
    dims = tuple(json.loads((SCHEMA1 / META).read_text())["dims"])
    r = decode(schema1_line(525), dims)
    rec = Recorder(SessionWriter(tmp_path / "s", {"mode": "DS", "dims": list(dims)}))
    rec.put(r)
    rec.close({})
    (back,) = read_session(tmp_path / "s").records
    assert back.outcome is not None and back.outcome.reason == "in_bin"


def test_the_schema_1_golden_session_reads() -> None:
    for s in (read_session(SCHEMA1),):
        assert s.meta["schema"] == "dsteleop.session/1"
        assert s.complete
        assert len(s.records) == s.meta["n_ticks"]
        assert s.records[0].X_reset is not None
        assert s.mode is Mode.parse(s.meta["mode"])
        kinds = {e.kind for r in s.records for e in r.plant.events}
        assert EventKind.GRASP in kinds and all(r.notes == () for r in s.records)


def test_an_unknown_schema_is_refused_with_one_line(tmp_path: Path) -> None:
    folder = tmp_path / "future"
    shutil.copytree(RECORDINGS / "demo-S-spoon", folder)
    meta = json.loads((folder / META).read_text())
    (folder / META).write_text(json.dumps({**meta, "schema": "dsteleop.session/99"}))
    with pytest.raises(InputError) as excinfo:
        read_session(folder)
    message = str(excinfo.value)
    assert "\n" not in message and "'dsteleop.session/99'" in message and SCHEMA in message
    r = subprocess.run(
        [*CLI, "replay", str(folder), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith("dsteleop replay: error:") and "dsteleop.session/99" in line
    # No schema at all is not a session this version reads either.
    del meta["schema"]
    (folder / META).write_text(json.dumps(meta))
    with pytest.raises(InputError, match="schema None"):
        read_session(folder)


def test_a_malformed_tick_names_its_line(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    shutil.copytree(RECORDINGS / "demo-S-spoon", folder)
    lines = (folder / TICKS).read_text().splitlines()
    d = json.loads(lines[4])
    del d["X_current"]
    lines[4] = json.dumps(d)
    (folder / TICKS).write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"ticks\.jsonl:5: malformed tick record") as excinfo:
        read_session(folder)
    assert "\n" not in str(excinfo.value)


# --- --config and --param -------------------------------------------------------------------


def write(path: Path, data: Any) -> Path:
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def run_cmd(tmp_path: Path, name: str, *args: str) -> dict[str, Any]:
    """`dsteleop run` on the demo for a few ticks, recorded; the session's meta.json."""
    folder = tmp_path / name
    assert main(["run", "--max-seconds", "0.2", "--record", str(folder), *args]) == 0
    meta: dict[str, Any] = json.loads((folder / META).read_text())
    return meta


def sim_cmd(tmp_path: Path, name: str, *args: str) -> dict[str, Any]:
    """`dsteleop sim` on 3 trajectories; its summary.json."""
    out = tmp_path / name
    argv = ["sim", "--trajectories", "3", "--no-figures", "--no-progress", "--out", str(out)]
    assert main([*argv, *args]) == 0
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    return summary


def test_run_reads_config_files_and_params(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flat = write(tmp_path / "flat.json", {"kappa": 8.0, "window": 7, "max_lead_m": 0.05})
    meta = run_cmd(tmp_path, "flat", "--config", str(flat))
    arb = meta["loop"]["arbitration"]
    assert (arb["kappa"], arb["window"], arb["max_lead_m"]) == (8.0, 7, 0.05)
    assert meta["loop"]["rate_hz"] == 30.0  # the loop's own defaults
    # The nested form ({"arbitration": ..., "loop": ...}, what a tuning run writes), with
    # --param over it and the command's flags over the file's loop settings.
    nested = write(
        tmp_path / "best.json",
        {
            "arbitration": {"kappa": 6.0, "q": 5.0},
            "loop": {"stale_limit_s": 0.2, "halt_ramp_s": 0.1, "mode": "S"},
            "objective": 0.5,
        },
    )
    meta = run_cmd(
        tmp_path, "nested", "--config", str(nested), "--param", "q=9", "--param", "window=3"
    )
    arb, loop = meta["loop"]["arbitration"], meta["loop"]
    assert (arb["kappa"], arb["q"], arb["window"]) == (6.0, 9.0, 3)
    assert (loop["stale_limit_s"], loop["halt_ramp_s"], loop["mode"]) == (0.2, 0.1, "S")
    assert meta["mode"] == "S"
    meta = run_cmd(tmp_path, "flag", "--config", str(nested), "--mode", "manual")
    assert meta["mode"] == "manual" and meta["loop"]["arbitration"]["kappa"] == 6.0
    # --param alone.
    meta = run_cmd(tmp_path, "param", "--param", "kappa=2.5")
    assert meta["loop"]["arbitration"]["kappa"] == 2.5
    capsys.readouterr()


def test_sim_reads_config_files_and_params(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flat = write(tmp_path / "flat.json", {"kappa": 8.0, "window": 7})
    arb = sim_cmd(tmp_path, "flat", "--config", str(flat))["config"]["arbitration"]
    assert (arb["kappa"], arb["window"], arb["p"]) == (8.0, 7, 4.0)
    nested = write(
        tmp_path / "best.json", {"arbitration": {"kappa": 6.0, "q": 5.0}, "loop": {"rate_hz": 30}}
    )
    arb = sim_cmd(tmp_path, "nested", "--config", str(nested), "--param", "q=9")["config"][
        "arbitration"
    ]
    assert (arb["kappa"], arb["q"]) == (6.0, 9.0)
    arb = sim_cmd(tmp_path, "param", "--param", "b=2")["config"]["arbitration"]
    assert arb["b"] == 2.0 and arb["kappa"] == 4.0
    capsys.readouterr()


BAD_CONFIGS: list[tuple[str, Any, str]] = [
    ("missing", None, "file not found"),
    ("not-json", "{ not json", "not a JSON file"),
    ("a-list", [1, 2], "expected a JSON object"),
    ("flat-unknown", {"kappa": 4.0, "nonsense": 1}, "unknown arbitration parameter(s): nonsense"),
    ("nested-unknown", {"arbitration": {"nonsense": 1}}, "unknown arbitration parameter"),
    ("section", {"arbitration": {}, "extras": {}}, "unknown section(s): extras"),
    ("section-type", {"arbitration": [1]}, "sections must be JSON objects"),
    ("value", {"kappa": -1}, "kappa must be finite and > 0"),
    ("type", {"kappa": "x"}, "kappa must be a number"),
]


@pytest.mark.parametrize("command", ["run", "sim"])
@pytest.mark.parametrize(("name", "content", "message"), BAD_CONFIGS)
def test_a_bad_config_file_exits_2_with_one_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    name: str,
    content: Any,
    message: str,
) -> None:
    path = tmp_path / f"{name}.json"
    if content is not None:
        write(path, content)
    extra = ["--max-seconds", "0.2"] if command == "run" else ["--out", str(tmp_path / "o")]
    code = main([command, "--config", str(path), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith(f"dsteleop {command}: error:"), err
    assert message in err[0]


@pytest.mark.parametrize("command", ["run", "sim"])
@pytest.mark.parametrize(
    ("param", "message"),
    [
        ("nonsense=1", "unknown arbitration parameter(s): nonsense"),
        ("kappa=abc", "--param kappa: not a number"),
        ("window=2.5", "--param window: must be a whole number, got 2.5"),
        ("kappa", "--param needs NAME=VALUE"),
        ("kappa=0", "kappa must be finite and > 0"),
    ],
)
def test_a_bad_param_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, param: str, message: str
) -> None:
    extra = ["--max-seconds", "0.2"] if command == "run" else ["--out", str(tmp_path / "o")]
    code = main([command, "--param", param, *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith(f"dsteleop {command}: error:"), err
    assert message in err[0]


@pytest.mark.parametrize(
    ("loop", "message"),
    [
        ({"nonsense": 1}, "unknown loop setting(s): nonsense"),
        ({"rate_hz": "fast"}, "rate_hz must be a positive number"),
        ({"mode": "XYZ"}, "unknown mode 'XYZ'"),
        ({"lost_policy": "panic"}, "unknown lost_policy 'panic'"),
    ],
)
def test_a_bad_loop_section_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], loop: dict[str, Any], message: str
) -> None:
    path = write(tmp_path / "c.json", {"arbitration": {}, "loop": loop})
    code = main(["run", "--config", str(path), "--max-seconds", "0.2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0], err


def test_a_non_numeric_input_delay_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write(tmp_path / "c.json", {"loop": {"input_delay_s": "x"}})
    code = main(["run", "--config", str(path), "--max-seconds", "0.2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "input_delay_s" in err[0], err


@pytest.mark.parametrize("command", ["run", "sim"])
def test_a_bad_config_file_has_no_traceback(tmp_path: Path, command: str) -> None:
    bad = write(tmp_path / "bad.json", {"arbitration": {"kappa": 4.0, "nonsense": 1}})
    extra = ["--max-seconds", "0.2"] if command == "run" else ["--out", str(tmp_path / "o")]
    r = subprocess.run(
        [*CLI, command, "--config", str(bad), *extra],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith(f"dsteleop {command}: error:") and "nonsense" in line


# --- the --source grammar -------------------------------------------------------------------


def test_parse_source_accepts_every_form(tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"")
    cases = {
        "demo": SourceSpec("demo"),
        "auto": SourceSpec("auto"),
        "synthetic": SourceSpec("synthetic"),
        "webcam:0": SourceSpec("webcam", "0"),
        "webcam:/dev/video2": SourceSpec("webcam", "/dev/video2"),
        "0": SourceSpec("webcam", "0"),
        "3": SourceSpec("webcam", "3"),
        "/dev/video0": SourceSpec("webcam", "/dev/video0"),
        f"video:{video}": SourceSpec("video", str(video)),
        str(video): SourceSpec("video", str(video)),
        "/no/such/clip.mp4": SourceSpec("video", "/no/such/clip.mp4"),  # opening says so
        f"images:{folder}": SourceSpec("images", str(folder)),
        str(folder): SourceSpec("images", str(folder)),
        " demo ": SourceSpec("demo"),
    }
    for text, spec in cases.items():
        got = parse_source(text)
        assert got == spec, text
        assert parse_source(str(got)) == got  # the printed form parses back


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("nosuch:thing", "unknown source kind 'nosuch'"),
        ("rtsp://camera/stream", "unknown source kind 'rtsp'"),
        ("webcam:", "needs a target"),
        ("video:", "needs a target"),
        ("images:", "needs a target"),
        ("demo:1", "takes no target"),
        ("synthetic:x", "takes no target"),
    ],
)
def test_parse_source_rejects_unknown_kinds_with_one_line(text: str, message: str) -> None:
    with pytest.raises(ConfigError) as excinfo:
        parse_source(text)
    assert message in str(excinfo.value) and "\n" not in str(excinfo.value)


def test_parse_source_rejects_an_empty_source() -> None:
    with pytest.raises(ConfigError, match="empty"):
        parse_source("")


def test_an_unknown_source_kind_stops_run_before_anything_opens(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code = main(["run", "--source", "nosuch:thing", "--max-seconds", "0.2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("dsteleop run: error:") and "unknown source kind" in err[0]
