"""Rerun recordings (docs/recordings.md), read back with Rerun's own reader of `.rrd` files
(`rerun.chunk.RrdReader`: the chunks as Arrow record batches, columns `Archetype:field`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import pytest
from numpy.typing import NDArray
from rerun.chunk import RrdReader

from dsteleop.app.replay.core import replay_session
from dsteleop.app.rrd import layout
from dsteleop.app.rrd.replay import write_part
from dsteleop.app.session.reader import read_session
from dsteleop.arbitration import STEP_ARRAYS, Mode

CLI = [sys.executable, "-m", "dsteleop.app.cli.main"]


@pytest.fixture(autouse=True)
def strict_rerun() -> Any:
    """Rerun raises instead of warning on what it cannot log (a dropped component)."""
    import rerun as rr

    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"
GOLDEN_V1 = Path(__file__).resolve().parent / "golden" / "schema1-demo-DS-spoon"


def cli(*args: str | Path, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout, check=False
    )


class Recording:
    """One recording of an `.rrd` file: its id and its chunks' rows by entity path."""

    def __init__(self, reader: RrdReader, index: int = 0) -> None:
        entry = reader.recordings()[index]
        self.recording_id = entry.recording_id
        self.application_id = entry.application_id
        self.batches: dict[str, list[pa.RecordBatch]] = {}
        for chunk in reader.stream(store=entry):
            self.batches.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())

    def component_columns(self) -> set[str]:
        """`/entity:Archetype:field` of every component column, static or not."""
        return {
            f"{entity}:{name}"
            for entity, batches in self.batches.items()
            for b in batches
            for name in b.schema.names
            if ":" in name and not name.startswith("rerun.")
        }


def load_recording(path: Path) -> Recording:
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1
    return Recording(reader)


def column(rec: Recording, entity: str, component: str) -> tuple[NDArray[np.float64], list[Any]]:
    """(tick times [s], values) of one entity's component (`Archetype:field`), one row per
    logged time, in time order."""
    t: list[float] = []
    values: list[Any] = []
    for b in rec.batches.get(f"/{entity}", []):
        if component not in b.schema.names or layout.TIMELINE not in b.schema.names:
            continue
        t += [ns * 1e-9 for ns in b.column(layout.TIMELINE).cast(pa.int64()).to_pylist()]
        values += b.column(component).to_pylist()
    order = np.argsort(np.array(t), kind="stable")
    return np.array(t, dtype=np.float64)[order], [values[k] for k in order]


def scalars(rec: Recording, entity: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    t, values = column(rec, entity, "Scalars:scalars")
    return t, np.array([np.nan if v is None else v[0] for v in values], dtype=np.float64)


def test_a_replay_of_two_modes_is_one_recording_on_one_timeline(tmp_path: Path) -> None:
    """Every per-dimension series of every mode, one row per tick, equal to the run's values;
    S and DS of the session side by side in one recording, on the same tick times."""
    session = read_session(RECORDINGS / "demo-DS-spoon")
    parts = tmp_path / "parts"
    traces = {}
    for mode in (Mode.S, Mode.DS):

        def sink(records: Any, scene: Any, mode: Mode = mode) -> None:
            write_part(
                parts / f"{mode.value}.rrd",
                session.name,
                mode.value,
                records,
                scene,
                session.meta["plant"] if mode is Mode.S else None,
            )

        traces[mode] = replay_session(session, mode, robot="recorded", sink=sink)
    from dsteleop.app.rrd.files import merge

    out = tmp_path / "both.rrd"
    merge(sorted(parts.glob("*.rrd")), out)
    reader = RrdReader(out)
    assert len(reader.recordings()) == 1
    rec = Recording(reader)
    assert rec.recording_id == session.name and rec.application_id == "dsteleop"
    times = {}
    for mode, tr in traces.items():
        T = len(tr)
        for q in STEP_ARRAYS:
            for i, dim in enumerate(session.dims):
                t, v = scalars(rec, layout.series(mode.value, q, dim))
                assert len(v) == T, (mode, q, dim)
                np.testing.assert_array_equal(v, getattr(tr.step, q)[:, i])
                times[mode] = t
        # The palm's translation per tick: the robot's achieved position.
        _, palm = column(rec, layout.palm(mode.value), "Transform3D:translation")
        np.testing.assert_allclose(np.array(palm)[:, 0], tr.p_robot, atol=1e-6)
    np.testing.assert_array_equal(times[Mode.S], times[Mode.DS])
    np.testing.assert_allclose(times[Mode.DS], traces[Mode.DS].t_s, atol=1e-9)
    # The recorded mode's replay against the recorded robot is the session's own arbitration.
    recorded = np.array([r.step.alpha for r in session.records if r.step is not None])
    _, yaw = scalars(rec, layout.series("DS", "alpha", "yaw"))
    np.testing.assert_allclose(yaw[traces[Mode.DS].arbitrated], recorded[:, 5], atol=1e-9)
    # Task events on the timeline, the true goals static.
    _, events = column(rec, layout.events("DS"), "TextLog:text")
    texts = [e[0] for e in events]
    assert any(x.startswith("grasp") for x in texts) and any(x.startswith("success") for x in texts)
    cols = rec.component_columns()
    assert any(f"/{layout.goal_true('pick')}:" in c for c in cols)


def test_replay_command_writes_the_scene_and_refuses_a_bad_path(tmp_path: Path) -> None:
    out = tmp_path / "rec.rrd"
    r = cli(
        "replay", RECORDINGS / "demo-S-spoon", "--modes", "S,DS", "--out", tmp_path / "o",
        "--no-plots", "--rerun", out,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["rerun"] == str(out)
    rec = load_recording(out)
    cols = rec.component_columns()
    # The robot's links and the utensils, from the scene description the browser draws.
    for frame in ("robot/palm", "spoon", "bin", "table"):
        assert any(f"/S/scene/{frame}:" in c for c in cols), frame
        assert any(f"/DS/scene/{frame}/visual_" in c for c in cols), frame
    assert not list(tmp_path.glob(".rerun-parts-*"))  # the parts are gone
    bad = cli("replay", RECORDINGS / "demo-S-spoon", "--out", tmp_path / "o2", "--rerun", "x.txt")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip().splitlines()[-1].endswith("--rerun must name a .rrd file, got x.txt")


def test_a_real_video_session_has_its_camera_frames_and_landmarks(
    shared_data: Path, tmp_path: Path
) -> None:
    video = shared_data / "videos" / "open_hand_wave_landscape.mp4"
    folder = tmp_path / "cam"
    r = cli("run", "--source", f"video:{video}", "--record", folder, "--record-video")
    assert r.returncode == 0, r.stderr
    session = read_session(folder)
    assert session.frames is not None
    n_frames = len([x for x in session.frames.read_text().splitlines() if x.strip()])
    out = tmp_path / "cam.rrd"
    r = cli("replay", folder, "--modes", "S,DS", "--out", tmp_path / "o", "--no-plots",
            "--rerun", out)  # fmt: skip
    assert r.returncode == 0, r.stderr
    rec = load_recording(out)
    t_img, blobs = column(rec, layout.CAMERA_IMAGE, "EncodedImage:blob")
    assert len(blobs) == n_frames > 100
    first = bytes(np.asarray(blobs[0][0], dtype=np.uint8))
    assert first[:2] == b"\xff\xd8"  # JPEG
    _, media = column(rec, layout.CAMERA_IMAGE, "EncodedImage:media_type")
    assert media[0] == ["image/jpeg"]
    t_lm, lm = column(rec, layout.CAMERA_LANDMARKS, "Points2D:positions")
    assert len(lm) > 0.8 * n_frames
    pts = np.array(lm[0])
    assert pts.shape == (21, 2) and (pts[:, 0] > 0).all() and (pts[:, 0] < 852).all()
    # Images and landmarks on the ticks' timeline: within the session's duration.
    _, alpha = scalars(rec, layout.series("DS", "alpha", "x"))
    assert len(alpha) == len(session.records)
    assert 0 <= t_img.min() and t_lm.max() <= session.records[-1].t_s - session.records[0].t_s + 0.1


def test_a_live_run_logs_every_tick_without_dropping(tmp_path: Path) -> None:
    out = tmp_path / "live.rrd"
    r = cli("run", "--source", "demo", "--seed", "2", "--rerun", out)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["rerun"]["ticks_dropped"] == 0
    assert summary["rerun"]["ticks_logged"] == summary["ticks"]
    rec = load_recording(out)
    for q in ("alpha", "B", "U_out"):
        _, v = scalars(rec, layout.series(layout.LIVE_ROOT, q, "yaw"))
        assert len(v) == summary["ticks"]
    _, status = column(rec, layout.status(layout.LIVE_ROOT), "TextLog:text")
    # The demo's link delay (docs/operator.md: 0.2 s each way) holds the first hand samples
    # back, so the first ticks may have no input yet; then the hand is tracked.
    assert status[0] in (["tracking"], ["lost: no input yet"])
    assert ["tracking"] in status
    cols = rec.component_columns()
    assert any("/live/scene/robot/palm:" in c for c in cols)


def test_a_live_run_inferring_its_goal_logs_its_belief_every_tick(tmp_path: Path) -> None:
    """`run --goal infer --rerun`: the belief in each candidate and the confidence per
    dimension, one row per tick; the probabilities of a tick's candidates sum to 1."""
    out = tmp_path / "infer.rrd"
    r = cli("run", "--source", "demo", "--goal", "infer", "--utensil", "spatula", "--seed", "1",
            "--rerun", out, "--record", tmp_path / "s")  # fmt: skip
    assert r.returncode == 0, r.stderr
    ticks = json.loads(r.stdout.strip().splitlines()[-1])["ticks"]
    rec = load_recording(out)
    # The live logger sends batches of ticks: a candidate's rows are those of the batches it
    # was a candidate in (the bin's from the place phase on), NaN on its other ticks there.
    total: dict[float, float] = {}
    series = {}
    for n in ("spoon", "spatula", "ladle", "bin"):
        t, v = scalars(rec, layout.belief(layout.LIVE_ROOT, n))
        series[n] = dict(zip(np.round(t, 6), v, strict=True))
        for tk, vk in zip(np.round(t, 6), v, strict=True):
            total[tk] = total.get(tk, 0.0) + (0.0 if np.isnan(vk) else vk)
    assert len(total) == ticks
    np.testing.assert_allclose(list(total.values()), 1.0, atol=1e-6)
    session = read_session(tmp_path / "s")
    t0 = session.records[0].t_s
    for rcd in session.records:
        got = series["spatula"].get(round(rcd.t_s - t0, 6))
        want = rcd.belief.of("spatula") if rcd.belief else np.nan
        if np.isnan(want):  # not a candidate then: no row, or NaN
            assert got is None or np.isnan(got), (rcd.k, got)
        else:
            assert got is not None and abs(got - want) < 1e-9, (rcd.k, got, want)
    for d in ("x", "yaw", "ring", "joint"):
        _, c = scalars(rec, layout.confidence(layout.LIVE_ROOT, d))
        assert len(c) == ticks and np.nanmin(c) >= 0.0 and np.nanmax(c) <= 1.0


def test_a_session_of_the_first_format_replays_into_a_recording(tmp_path: Path) -> None:
    out = tmp_path / "old.rrd"
    r = cli("replay", GOLDEN_V1, "--as-recorded", "--out", tmp_path / "o", "--no-plots",
            "--rerun", out)  # fmt: skip
    assert r.returncode == 0, r.stderr
    s = read_session(GOLDEN_V1)
    rec = load_recording(out)
    _, v = scalars(rec, layout.series("DS", "alpha", "x"))
    recorded = np.array([np.nan if x.step is None else x.step.alpha[0] for x in s.records])
    np.testing.assert_allclose(v, recorded, atol=1e-9)


@pytest.mark.parametrize("package", ["arbitration", "tracking", "robot"])
def test_rerun_is_not_imported_by_the_core_packages(package: str) -> None:
    code = (
        "import importlib, pkgutil, sys\n"
        f"import dsteleop.{package} as p\n"
        "for m in pkgutil.iter_modules(p.__path__):\n"
        f"    importlib.import_module('dsteleop.{package}.' + m.name)\n"
        "print('rerun' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_the_scene_and_the_goals_log_without_a_dropped_component(tmp_path: Path) -> None:
    """Every shape of the kitchen scene (boxes, spheres, capsules, meshes) and the true
    goals, in strict mode: Rerun raises on anything it would drop."""
    from dsteleop.app.plants.kitchen import KitchenTask
    from dsteleop.app.rrd import log as rlog
    from dsteleop.app.rrd.files import file_recording

    task = KitchenTask(utensil="spoon", seed=0, export_scene=True)
    try:
        task.reset()
        scene, meta = task.scene(), task.describe()
    finally:
        task.close()
    assert scene is not None
    rec = file_recording(tmp_path / "scene.rrd", "scene")
    rlog.log_scene_geometry(rec, "DS", scene)
    rlog.log_true_goals(rec, meta)
    rec.send_blueprint(rlog.blueprint(["S", "DS"], camera=True))
    rec.flush()
    rec.disconnect()
    cols = load_recording(tmp_path / "scene.rrd").component_columns()
    kinds = {c.split(":", 1)[1] for c in cols if "/visual_" in c}
    # Boxes and spheres (half sizes), meshes (the file's bytes), each at its offset.
    assert {"Boxes3D:half_sizes", "Ellipsoids3D:half_sizes", "Asset3D:blob"} <= kinds
    assert {"Transform3D:quaternion", "Transform3D:translation"} <= kinds
    assert any("/goal_true/pick:Transform3D:quaternion" in c for c in cols)
    assert any("/goal_true/place:Transform3D:translation" in c for c in cols)
    assert any("/goal_true/place:TransformAxes3D:axis_length" in c for c in cols)
