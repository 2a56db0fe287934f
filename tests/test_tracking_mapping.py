"""Camera -> robot workspace mapping: axes, calibration without jumps, limits, fingers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.typing import NDArray

from dsteleop.arbitration import HandState, so3_exp, so3_log
from dsteleop.tracking import (
    HandSample,
    MappingConfig,
    WorkspaceMapping,
    palm_facing_camera,
    robot_openness,
)

P0 = np.array([0.0, 0.0, 0.5])
UNIT = MappingConfig(scale=(1.0, 1.0, 1.0))


def sample(
    p: NDArray[np.float64],
    R: NDArray[np.float64] | None = None,
    g: NDArray[np.float64] | None = None,
) -> HandSample:
    R = palm_facing_camera() if R is None else R
    g = np.ones(5) if g is None else g
    return HandSample(
        seq=0,
        t_capture_s=0.0,
        t_tracked_s=0.0,
        detected=True,
        handedness="Right",
        score=1.0,
        landmarks_image=None,
        landmarks_world=None,
        p_cam_palm_m=np.asarray(p, dtype=np.float64),
        R_cam_palm=R,
        openness=g,
        raw_p_cam_palm_m=np.asarray(p, dtype=np.float64),
        raw_R_cam_palm=R,
        raw_openness=g,
        width_px=640,
        height_px=480,
    )


def test_first_map_is_the_neutral_pose() -> None:
    m = WorkspaceMapping(UNIT)
    x = m.map(sample(P0))
    assert x.position == pytest.approx(UNIT.neutral_position_m)
    assert x.rotation == pytest.approx(np.eye(3))
    assert x.openness.shape == (4,)


@pytest.mark.parametrize(
    ("mirror", "d_cam", "d_base"),
    [
        # Camera facing the operator: towards the camera is forward, image right is the
        # operator's left, image up is up.
        (True, [0.0, 0.0, -0.1], [0.1, 0.0, 0.0]),
        (True, [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]),
        (True, [0.0, -0.1, 0.0], [0.0, 0.0, 0.1]),
        # Camera behind the operator, looking where they look.
        (False, [0.0, 0.0, 0.1], [0.1, 0.0, 0.0]),
        (False, [-0.1, 0.0, 0.0], [0.0, 0.1, 0.0]),
        (False, [0.0, -0.1, 0.0], [0.0, 0.0, 0.1]),
    ],
)
def test_camera_axes_map_to_robot_axes(
    mirror: bool, d_cam: list[float], d_base: list[float]
) -> None:
    cfg = MappingConfig(scale=(2.0, 2.0, 2.0), mirror=mirror)
    m = WorkspaceMapping(cfg)
    m.map(sample(P0))
    x = m.map(sample(P0 + np.array(d_cam)))
    assert x.position - np.array(cfg.neutral_position_m) == pytest.approx(2.0 * np.array(d_base))


def test_turning_the_hand_about_the_vertical_yaws_the_robot() -> None:
    m = WorkspaceMapping(UNIT)
    m.map(sample(P0))
    # Camera "up" is -y_cam; a rotation of 0.4 rad about it maps to 0.4 rad about base z.
    R = so3_exp(np.array([0.0, -0.4, 0.0])) @ palm_facing_camera()
    x = m.map(sample(P0, R))
    assert so3_log(x.rotation) == pytest.approx([0.0, 0.0, 0.4])


def test_calibrate_recentres_without_a_jump() -> None:
    m = WorkspaceMapping(UNIT)
    m.map(sample(P0))
    moved = sample(P0 + np.array([0.05, 0.02, -0.1]), so3_exp(np.array([0.2, 0.1, -0.3])))
    before = m.map(moved)
    m.calibrate(moved)
    after = m.map(moved)
    assert after.position == pytest.approx(before.position, abs=1e-12)
    assert after.rotation == pytest.approx(before.rotation, abs=1e-12)
    # From the new anchor the hand drives the robot relative to where it is.
    x = m.map(sample(P0 + np.array([0.05, 0.02, -0.2]), moved.R_cam_palm))
    assert x.position - before.position == pytest.approx([0.1, 0.0, 0.0])
    # ...unless asked for the neutral pose explicitly.
    m.calibrate(moved, to_neutral=True)
    assert m.map(moved).position == pytest.approx(UNIT.neutral_position_m)


def test_workspace_limits_clip_and_recalibration_at_the_limit_has_no_dead_zone() -> None:
    m = WorkspaceMapping(UNIT)
    m.map(sample(P0))
    far = sample(P0 + np.array([0.0, 0.0, -1.0]))  # 1 m towards the camera: beyond x max
    x = m.map(far)
    assert x.position[0] == pytest.approx(UNIT.workspace_max_m[0])
    m.calibrate(far)
    back = m.map(sample(P0 + np.array([0.0, 0.0, -0.95])))
    assert back.position[0] == pytest.approx(UNIT.workspace_max_m[0] - 0.05)


def test_robot_fingers_average_ring_and_little() -> None:
    g = robot_openness(np.array([0.1, 0.2, 0.3, 0.4, 0.8]))
    assert g == pytest.approx([0.1, 0.2, 0.3, 0.6])
    m = WorkspaceMapping(UNIT)
    assert m.map(sample(P0, g=np.array([0.1, 0.2, 0.3, 0.4, 0.8]))).openness == pytest.approx(g)


@given(
    st.lists(st.floats(-0.1, 0.1), min_size=3, max_size=3),
    st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3),
    st.booleans(),
)
def test_to_camera_inverts_map(d: list[float], w: list[float], mirror: bool) -> None:
    m = WorkspaceMapping(MappingConfig(mirror=mirror))
    m.map(sample(P0))
    R = so3_exp(np.array(w)) @ palm_facing_camera()
    s = sample(P0 + np.array(d), R)
    x = m.map(s)
    p_cam, R_cam = m.to_camera(HandState(x.position, x.rotation, x.openness))
    inside = np.all(x.position > np.array(m.config.workspace_min_m)) and np.all(
        x.position < np.array(m.config.workspace_max_m)
    )
    if inside:
        assert p_cam == pytest.approx(s.p_cam_palm_m, abs=1e-9)
    assert R_cam == pytest.approx(R, abs=1e-9)


def test_sample_without_pose_is_refused() -> None:
    nan = sample(np.full(3, np.nan))
    with pytest.raises(ValueError, match="no hand pose"):
        WorkspaceMapping().map(nan)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"scale": (1.0, 0.0, 1.0)},
        {"workspace_min_m": (0.9, -0.4, 0.0)},
        {"neutral_position_m": (2.0, 0.0, 0.3)},
        {"neutral_rotvec_rad": (4.0, 0.0, 0.0)},
        {"scale": (1.0, 1.0)},
    ],
)
def test_mapping_config_is_validated(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        MappingConfig(**kwargs)  # type: ignore[arg-type]  # deliberately invalid values
