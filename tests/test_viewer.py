"""The browser view without a browser: what it shows, how it reads the scene, how serve runs.

Snapshots come from the real loop (the built-in demo, headless on a manual clock): no
hand-made data. The real-browser tests are in test_viewer_browser.py.
"""

from __future__ import annotations

import dataclasses
import json
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from dsteleop.app.observers import Snapshot
from dsteleop.errors import DsteleopError

if TYPE_CHECKING:
    from dsteleop.app.loop import TeleopLoop
    from dsteleop.app.setup import Built
    from dsteleop.app.timing import ManualClock

REPO = Path(__file__).resolve().parents[1]
DSTELEOP = [sys.executable, "-m", "dsteleop.app.cli"]


# ----------------------------------------------------------------------------- fixtures


def _demo_loop(export_scene: bool = True) -> Built:
    from dsteleop.app.loop import LoopConfig
    from dsteleop.app.setup import Setup, build

    return build(Setup(source="demo", loop=LoopConfig(), realtime=False, export_scene=export_scene))


def _manual_clock(loop: TeleopLoop) -> ManualClock:
    """The clock of a headless loop (realtime=False), which the test advances by hand."""
    from dsteleop.app.timing import ManualClock

    assert isinstance(loop.clock, ManualClock)
    return loop.clock


@pytest.fixture(scope="module")
def snapshots() -> list[Snapshot]:
    """Every snapshot of 150 ticks (5 s) of the headless demo."""
    built = _demo_loop()
    loop = built.loop
    out: list[Snapshot] = []
    sub = loop.broadcaster.subscribe()
    try:
        for _ in range(150):
            loop.tick(loop.clock.now())
            snap = sub.latest()
            assert snap is not None
            out.append(snap)
            _manual_clock(loop).advance(loop.config.dt_s)
    finally:
        sub.close()
        loop.close()
    return out


def _tracking(snapshots: list[Snapshot]) -> Snapshot:
    return next(s for s in reversed(snapshots) if s.status == "tracking")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def busy_port() -> Iterator[int]:
    """A port with a listening socket on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield int(s.getsockname()[1])


# ----------------------------------------------------------------------------- panel

_ROW = re.compile(
    r'data-dim="([^"]+)" data-alpha="([^"]+)" data-ph="([^"]+)" data-pr="([^"]+)" '
    r'data-b="([^"]+)">.*?style="width:([0-9.]+)%"'
)


def test_gauges_show_every_dimension_with_its_values(snapshots: list[Snapshot]) -> None:
    from dsteleop.app.viewer_panel import gauges_html

    snap = _tracking(snapshots)
    rows = _ROW.findall(gauges_html(snap))
    assert [r[0] for r in rows] == list(snap.dims)
    assert len(rows) == 6 + 4
    got = np.array([[float(v) for v in r[1:]] for r in rows])
    want = np.stack([snap.alpha, snap.P_human, snap.P_robot, snap.B], axis=1)
    np.testing.assert_allclose(got[:, :4], want, atol=5e-4)
    np.testing.assert_allclose(got[:, 4], 100 * np.clip(snap.alpha, 0, 1), atol=0.05)


def test_status_says_what_the_loop_does_and_why(snapshots: list[Snapshot]) -> None:
    from dsteleop.app.viewer_panel import status_html

    snap = _tracking(snapshots)
    lost = dataclasses.replace(snap, status="lost", reason="camera stalled")
    text = status_html(lost)
    assert 'data-status="lost"' in text and "camera stalled" in text
    text = status_html(snap, {"tabs": 2}, rate_hz=29.97)
    assert 'data-status="tracking"' in text
    assert f'data-mode="{snap.mode}"' in text and f'data-phase="{snap.phase}"' in text
    assert 'data-rate-hz="29.97"' in text and "29.97 Hz" not in text and "30.0 Hz" in text
    assert "tabs" in text


def test_alpha_history_keeps_a_window(snapshots: list[Snapshot]) -> None:
    from dsteleop.app.viewer_panel import AlphaHistory

    h = AlphaHistory(snapshots[0].dims, 20)
    for s in snapshots:
        h.push(s.t_s, s.alpha)
    t, *alphas = h.data()
    assert len(t) == 20 and len(alphas) == 10
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose([a[-1] for a in alphas], snapshots[-1].alpha)


def test_camera_image_draws_the_tracked_landmarks(snapshots: list[Snapshot]) -> None:
    from dsteleop.app.viewer_panel import camera_image

    snap = next(s for s in reversed(snapshots) if s.hand is not None and s.hand.sample.detected)
    img = camera_image(snap.hand, width_px=160)
    assert img is not None and img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert (img != 60).any(axis=2).sum() > 50  # skeleton drawn on the grey canvas
    assert camera_image(None) is None


# ----------------------------------------------------------------------------- scene


def test_robot_scene_description_is_read_without_robot_types() -> None:
    from dsteleop.app.plant import KitchenPlant
    from dsteleop.app.viewer_scene import frame_order, frame_poses, visual_shapes

    plant = KitchenPlant(export_scene=True)
    try:
        plant.reset()
        geo = plant.scene_description()
        poses = plant.env.poses()
    finally:
        plant.close()
    shapes = visual_shapes(geo)
    assert len(shapes) == len(geo.visuals)
    frames, static = frame_order(geo)
    assert frames == geo.frames and static == geo.static
    assert {s.frame for s in shapes} <= set(frames)
    meshes = [s for s in shapes if s.kind == "mesh"]
    assert meshes and all(Path(str(s.mesh_path)).is_file() for s in meshes)
    boxes = [s for s in shapes if s.kind == "box"]
    assert boxes and all(len(s.size_m) == 3 for s in boxes)
    fp = frame_poses(poses, frames)
    assert fp is not None and fp.names == frames
    assert fp.positions_m.shape == (len(frames), 3) and fp.wxyz.shape == (len(frames), 4)
    np.testing.assert_allclose(np.linalg.norm(fp.wxyz, axis=1), 1.0, atol=1e-9)


def test_only_moved_frames_are_sent_and_static_ones_once(snapshots: list[Snapshot]) -> None:
    from dsteleop.app.viewer_scene import POSITION_DEADBAND_M, ChangedRows, FramePoses

    scene = snapshots[-1].scene
    names = tuple(f"f{i}" for i in range(len(scene.positions_m)))
    P, Q = np.array(scene.positions_m), np.array(scene.wxyz)
    rows = ChangedRows(static={"f0"})
    assert rows.rows(FramePoses(names, P, Q)) == list(range(len(names)))
    assert rows.rows(FramePoses(names, P, Q)) == []
    P2 = P.copy()
    P2[3, 0] += 10 * POSITION_DEADBAND_M
    P2[0, 0] += 1.0  # a "static" frame never moves again in the view
    P2[4, 1] += 0.2 * POSITION_DEADBAND_M  # below the deadband
    assert rows.rows(FramePoses(names, P2, Q)) == [3]


def test_robot_poses_in_snapshots_move_the_arm(snapshots: list[Snapshot]) -> None:
    first = next(s for s in snapshots if s.scene is not None)
    last = snapshots[-1]
    moved = np.abs(last.scene.positions_m - first.scene.positions_m).max(axis=1)
    assert (moved > 1e-3).sum() >= 3  # arm links follow the palm


# ----------------------------------------------------------------------------- viewer


def test_viewer_follows_a_live_loop_and_never_posts_on_its_own() -> None:
    from dsteleop.app.viewer import Viewer, ViewerConfig

    built = _demo_loop()
    loop = built.loop
    viewer = Viewer(
        loop.broadcaster, loop.controls, loop.plant.scene_description(), ViewerConfig(port=0)
    )
    try:
        viewer.start()
        assert viewer.url == f"http://127.0.0.1:{viewer.port}/" and viewer.port > 0
        for _ in range(120):
            loop.tick(loop.clock.now())
            _manual_clock(loop).advance(loop.config.dt_s)
            time.sleep(0.005)
        deadline = time.monotonic() + 10.0
        while viewer.stats.panel_updates < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert viewer.stats.scene_updates >= 2 and viewer.stats.panel_updates >= 2
        assert viewer.stats.errors == 0
        assert viewer.scene.frames  # drawn from the robot's description
        assert viewer.scene.robot_hand is None  # the real hand is drawn, not a proxy
        assert loop.controls.take().empty  # a sink: nothing is posted without a person
    finally:
        viewer.close()
        loop.close()
    assert viewer.server is None


def test_port_in_use_is_one_clear_error(busy_port: int) -> None:
    from dsteleop.app.controls import Controls
    from dsteleop.app.observers import Broadcaster
    from dsteleop.app.viewer import Viewer, ViewerConfig, check_port_free

    with pytest.raises(DsteleopError, match=f"port {busy_port} is already in use"):
        check_port_free("127.0.0.1", busy_port)
    with pytest.raises(DsteleopError, match=f"port {busy_port}"):
        Viewer(Broadcaster(), Controls(), None, ViewerConfig(port=busy_port))
    with pytest.raises(DsteleopError, match="port must be"):
        ViewerConfig(port=70000)


def test_viewer_imports_no_pybullet() -> None:
    code = (
        "import sys, dsteleop.app.viewer, dsteleop.app.viewer_scene, dsteleop.app.viewer_panel;"
        "sys.exit('pybullet' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


# ----------------------------------------------------------------------------- serve


def test_serve_with_port_in_use_exits_2_with_one_line(busy_port: int) -> None:
    res = subprocess.run(
        [*DSTELEOP, "serve", "--source", "demo", "--port", str(busy_port)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert res.returncode == 2
    errors = [ln for ln in res.stderr.splitlines() if "error" in ln]
    assert len(errors) == 1 and f"port {busy_port}" in errors[0]
    assert "Traceback" not in res.stderr


def test_serve_on_all_interfaces_warns_who_can_steer(busy_port: int) -> None:
    # The port is taken, so the server never really listens on all interfaces here.
    res = subprocess.run(
        [*DSTELEOP, "serve", "--source", "demo", "--host", "0.0.0.0", "--port", str(busy_port)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert "anyone who can reach port" in res.stderr
    assert res.returncode == 2


def test_serve_rejects_bad_arguments() -> None:
    for args in (["--mode", "fast"], ["--source", "kinect"], ["--port", "-1"]):
        res = subprocess.run(
            [*DSTELEOP, "serve", *args], capture_output=True, text=True, timeout=60, check=False
        )
        assert res.returncode == 2 and "Traceback" not in res.stderr, args


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_serve_stops_cleanly_with_a_complete_recording(tmp_path: Path, sig: int) -> None:
    from dsteleop.app.recording import read_session

    port = _free_port()
    proc = subprocess.Popen(
        [*DSTELEOP, "serve", "--source", "demo", "--port", str(port), "--record", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stderr is not None
        lines = []
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            lines.append(line)
            if f"open http://127.0.0.1:{port}/" in line or not line:
                break
        assert any(f"http://127.0.0.1:{port}/" in ln for ln in lines), "".join(lines)
        time.sleep(3.0)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["stopped_by"] == signal.Signals(sig).name
    assert summary["timing"]["ticks"] > 30
    session = read_session(Path(summary["recording"]))
    assert session.folder.parent == tmp_path
    assert session.complete and len(session.ticks) > 30
    assert "Traceback" not in err


def _stalled_client(port: int) -> socket.socket:
    """A websocket client that completes the handshake and then never reads."""
    import base64
    import os

    import viser

    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(
        (
            f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            "Sec-WebSocket-Version: 13\r\n"
            f"Sec-WebSocket-Protocol: viser-v{viser.__version__}\r\n\r\n"
        ).encode()
    )
    return s


@pytest.mark.slow
def test_a_stalled_tab_never_slows_the_loop() -> None:
    from dsteleop.app.loop import LoopConfig
    from dsteleop.app.setup import Setup, build
    from dsteleop.app.viewer import Viewer, ViewerConfig

    built = build(Setup(source="demo", loop=LoopConfig(), realtime=True, export_scene=True))
    loop = built.loop
    viewer = Viewer(
        loop.broadcaster, loop.controls, loop.plant.scene_description(), ViewerConfig(port=0)
    )
    viewer.start()
    stalled = [_stalled_client(viewer.port) for _ in range(2)]
    sub = loop.broadcaster.subscribe()
    runner = threading.Thread(target=loop.run, daemon=True)
    try:
        runner.start()
        time.sleep(2.0)  # the stalled clients' buffers fill up
        first = sub.latest()
        updates = viewer.stats.scene_updates
        time.sleep(4.0)
        last = sub.latest()
    finally:
        loop.stop()
        runner.join(timeout=5.0)
        sub.close()
        for s in stalled:
            s.close()
        viewer.close()
        loop.close()
    assert first is not None and last is not None and last.tick > first.tick
    rate = (last.tick - first.tick) / (last.t_s - first.t_s)
    # Held, not blocked: a loop waiting on a stalled client would fall to a few Hz. The margin
    # (80 % of 30 Hz) absorbs a shared 2-core machine; the 30 Hz / p99 jitter targets are
    # measured by `dsteleop bench --only viewer`, not here.
    assert rate >= 24.0
    assert viewer.stats.scene_updates - updates >= 60  # the view kept drawing (>= 15 Hz)
    assert viewer.stats.errors == 0
