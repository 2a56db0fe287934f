"""Palm pose and openness estimator: ground-truth round trips with the synthetic hand."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from dsteleop.arbitration import so3_exp, so3_log
from dsteleop.tracking import (
    CameraIntrinsics,
    Detection,
    Handedness,
    LandmarkNoise,
    PoseConfig,
    estimate_palm_pose,
    hand_scale_for_depth,
    palm_facing_camera,
    palm_rotation,
    synthesize_detection,
)
from dsteleop.tracking.landmarks import FINGER_NAMES

CAM = CameraIntrinsics.from_hfov(640, 480, 60.0)
CFG = PoseConfig()


def random_pose(
    rng: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A hand anywhere an operator would hold it: 0.35-0.8 m away, in view, turned up to
    ~70 deg (sigma 0.5 rad per axis) from facing the camera, any finger openness."""
    z = rng.uniform(0.35, 0.8)
    p = np.array([rng.uniform(-0.25, 0.25) * z, rng.uniform(-0.18, 0.18) * z, z])
    R = so3_exp(rng.normal(0.0, 0.5, 3)) @ palm_facing_camera()
    return p, R, rng.uniform(0.0, 1.0, 5)


def rot_err_deg(A: NDArray[np.float64], B: NDArray[np.float64]) -> float:
    return float(np.degrees(np.linalg.norm(so3_log(A @ B.T))))


def mirror(d: Detection) -> Detection:
    """The same detection in a left-right flipped image."""
    img = d.landmarks_image.copy()
    img[:, 0] = 1.0 - img[:, 0]
    world = None if d.landmarks_world is None else d.landmarks_world * np.array([-1.0, 1, 1])
    return Detection(img, world, d.handedness, d.score)


@pytest.mark.parametrize("hand", ["Right", "Left"])
@pytest.mark.parametrize("use_world", [True, False])
def test_round_trip_without_noise_is_exact(hand: Handedness, use_world: bool) -> None:
    # The model defines openness and palm size exactly as the estimator measures them, and
    # the back-projection is exact pinhole geometry: only rounding errors remain.
    rng = np.random.default_rng(1)
    for _ in range(100):
        p, R, g = random_pose(rng)
        d = synthesize_detection(p, R, g, CAM, handedness=hand)
        if not use_world:
            d = Detection(d.landmarks_image, None, d.handedness, d.score)
        est = estimate_palm_pose(d, CAM, CFG)
        assert np.linalg.norm(est.p_cam_palm_m - p) < 1e-9
        assert rot_err_deg(est.R_cam_palm, R) < 1e-6
        assert np.abs(est.openness - g).max() < 1e-9


def test_round_trip_in_a_mirrored_image() -> None:
    rng = np.random.default_rng(2)
    for _ in range(50):
        p, R, g = random_pose(rng)
        d = mirror(synthesize_detection(p, R, g, CAM))
        est = estimate_palm_pose(d, CAM, CFG, mirrored=True)
        assert np.linalg.norm(est.p_cam_palm_m - p) < 1e-9
        assert rot_err_deg(est.R_cam_palm, R) < 1e-6
        assert np.abs(est.openness - g).max() < 1e-9


def test_round_trip_under_detector_noise() -> None:
    """500 random poses with sigma = 1 px on image landmarks and 2 mm on world landmarks
    (MediaPipe's frame-to-frame landmark noise on a still hand is of this order).

    Bounds, from first-order error propagation, with a margin of ~1.5x:
      * depth: Z = palm_size_m / size(b); the palm spans size ~ fx * 0.0415 / Z px (29-66 px
        here) over 6 points, so sigma_Z / Z ~ 1 px / (size * sqrt(6/2)) <= 2 %; the p95
        relative error must stay below 5 %;
      * orientation: wrist-MCP baselines of ~8 cm with 2 mm noise tilt each axis by
        ~2 mm * sqrt(2) / 8 cm ~ 2 deg; the p95 angle error must stay below 10 deg;
      * openness: a joint angle between 2-4 cm phalanges whose three points each move by
        2 mm turns by ~0.1-0.15 rad; the sum over a finger's three joints (~0.2 rad) is
        spread over its 2.8-3.2 rad range (sigma ~ 0.07), the thumb's two (~0.15 rad) over
        its 1.1 rad range (sigma ~ 0.14): pooled over all fingers the p95 |error| is
        ~0.17; the bound is 0.25.
    """
    rng = np.random.default_rng(3)
    noise = LandmarkNoise(image_px=1.0, world_m=0.002)
    rel: list[float] = []
    ang: list[float] = []
    dg: list[float] = []
    for i in range(500):
        p, R, g = random_pose(rng)
        hand: Handedness = "Right" if i % 2 else "Left"
        d = synthesize_detection(p, R, g, CAM, handedness=hand, noise=noise, rng=rng)
        est = estimate_palm_pose(d, CAM, CFG)
        rel.append(np.linalg.norm(est.p_cam_palm_m - p) / p[2])
        ang.append(rot_err_deg(est.R_cam_palm, R))
        dg.extend(np.abs(est.openness - g))
    assert np.percentile(rel, 95) < 0.05
    assert np.percentile(ang, 95) < 10.0
    assert np.percentile(dg, 95) < 0.25
    # Unbiased: the median errors sit well inside the bounds.
    assert np.median(rel) < 0.02 and np.median(ang) < 5.0 and np.median(dg) < 0.08


@pytest.mark.parametrize("finger", range(5))
def test_openness_is_monotonic_in_each_finger(finger: int) -> None:
    p, R = np.array([0.0, 0.0, 0.5]), palm_facing_camera()
    values = []
    for o in np.linspace(0.0, 1.0, 11):
        g = np.full(5, 0.5)
        g[finger] = o
        values.append(estimate_palm_pose(synthesize_detection(p, R, g, CAM), CAM, CFG).openness)
    column = np.array(values)[:, finger]
    assert np.all(np.diff(column) > 0), FINGER_NAMES[finger]
    others = np.delete(np.array(values), finger, axis=1)
    assert np.allclose(others, 0.5)


def test_hand_scale_scales_depth() -> None:
    # A hand 20 % larger than the reference looks 20 % closer unless calibrated.
    p, R, g = np.array([0.05, -0.02, 0.6]), palm_facing_camera(), np.ones(5)
    big = PoseConfig(hand_scale=1.2)
    d = synthesize_detection(p, R, g, CAM, config=big)
    assert estimate_palm_pose(d, CAM, CFG).p_cam_palm_m == pytest.approx(p / 1.2, abs=1e-9)
    assert estimate_palm_pose(d, CAM, big).p_cam_palm_m == pytest.approx(p, abs=1e-9)


def test_hand_scale_calibration_from_one_frame_at_a_known_depth() -> None:
    p, R, g = np.array([0.05, -0.02, 0.6]), palm_facing_camera(), np.ones(5)
    d = synthesize_detection(p, R, g, CAM, config=PoseConfig(hand_scale=0.85))
    scale = hand_scale_for_depth(estimate_palm_pose(d, CAM, CFG), 0.6, CFG)
    assert scale == pytest.approx(0.85)
    est = estimate_palm_pose(d, CAM, PoseConfig(hand_scale=scale))
    assert est.p_cam_palm_m == pytest.approx(p, abs=1e-9)


def test_degenerate_landmarks_give_a_non_finite_pose() -> None:
    d = Detection(np.full((21, 3), 0.5), np.zeros((21, 3)), "Right", 0.9)
    assert not estimate_palm_pose(d, CAM, CFG).is_finite()


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False), min_size=63, max_size=63)
)
def test_palm_frame_is_a_proper_rotation(values: list[float]) -> None:
    pts = np.asarray(values).reshape(21, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        R = palm_rotation(pts)
    if np.isfinite(R).all():
        # Far from degenerate inputs (collinear wrist and MCPs) the frame is orthonormal.
        assert R.T @ R == pytest.approx(np.eye(3), abs=1e-6)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"hfov_deg": 0.0},
        {"hand_scale": -1.0},
        {"palm_size_m": float("nan")},
        {"theta_open_rad": (1.0, 1.0, 1.0, 1.0)},
        {"theta_open_rad": (2.0, 0.8, 0.6, 0.5, 0.6)},
    ],
)
def test_pose_config_is_validated(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        PoseConfig(**kwargs)  # type: ignore[arg-type]  # deliberately invalid values


def test_intrinsics_projection_matches_field_of_view() -> None:
    k = CameraIntrinsics.from_hfov(640, 480, 90.0)
    # At 90 deg, a point at 45 deg lands on the image border.
    assert k.project(np.array([1.0, 0.0, 1.0])) == pytest.approx([640.0, 240.0])
