"""Models and targets beyond the default: fisheye lenses, partial ChArUco views, outlier views."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from backend.calib.board.detection import Detection, detect_board
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image

FISHEYE = CameraIntrinsics("fisheye-equidistant", 1280, 720,
                           np.array([[600.0, 0, 641.5], [0, 599.0, 359.2], [0, 0, 1]]), [0.05, -0.01, 0.004, -0.001])
"""A fisheye whose image corners see about 70 degrees off axis."""
PINHOLE = CameraIntrinsics("pinhole-radtan", 1280, 720,
                           np.array([[900.0, 0, 640.0], [0, 900.0, 360.0], [0, 0, 1]]), [-0.1, 0.04, 0, 0, 0])
CHECKERBOARD = BoardSpec.parse("checkerboard:9x6:0.04")
CHARUCO = BoardSpec.parse("charuco:10x7:0.04:0.03:DICT_5X5_100")


def rendered_views(camera: CameraIntrinsics, board: BoardSpec, count: int, seed: int,
                   hide_left_px: int = 0) -> list[View]:
    """Render and detect ``count`` views; every other view has its left ``hide_left_px`` columns covered."""
    rng = np.random.default_rng(seed)
    views = []
    for i, T_camera_board in enumerate(board_poses(camera, board, count, seed)):
        image = render_board_image(camera, board, T_camera_board, rng)
        if hide_left_px and i % 2:
            image[:, :hide_left_px] = 90
        detection = detect_board(image, board)
        if detection is not None:
            views.append(View(f"view{i:02d}", detection))
    return views


def intrinsic_errors(camera: CameraIntrinsics, truth: CameraIntrinsics, std: dict) -> np.ndarray:
    estimate = np.r_[camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2], camera.dist]
    true = np.r_[truth.K[0, 0], truth.K[1, 1], truth.K[0, 2], truth.K[1, 2], truth.dist]
    sigma = np.r_[std["fx"], std["fy"], std["cx"], std["cy"], std["dist"]]
    keep = sigma > 0
    return (estimate[keep] - true[keep]) / sigma[keep]


@pytest.mark.slow
def test_fisheye_equidistant_recovers_truth():
    views = rendered_views(FISHEYE, CHECKERBOARD, 18, seed=0)
    assert len(views) >= 16
    result = calibrate_intrinsics(views, CHECKERBOARD, FISHEYE.image_size,
                                  IntrinsicsSettings(model="fisheye-equidistant"))
    assert result.camera.model == "fisheye-equidistant" and result.camera.dist.size == 4
    assert result.correlation_names == ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"]
    z = intrinsic_errors(result.camera, FISHEYE, result.std)
    assert np.all(np.abs(z) < 3), np.round(z, 2)
    assert abs(result.camera.K[0, 0] - 600.0) < 1.0
    assert result.projection_uncertainty["max_px"] < 2.0


@pytest.mark.slow
def test_charuco_partial_views_are_used():
    views = rendered_views(PINHOLE, CHARUCO, 16, seed=3, hide_left_px=500)
    partial = [v for v in views if len(v.detection.ids) < CHARUCO.n_corners]
    assert len(partial) >= 4, "covering part of the image must leave partial ChArUco views"
    assert all(len(v.detection.ids) >= 6 for v in partial)
    result = calibrate_intrinsics(views, CHARUCO, PINHOLE.image_size)
    assert all(v.used for v in result.views)
    assert result.rms_px < 0.15
    z = intrinsic_errors(result.camera, PINHOLE, result.std)
    assert np.all(np.abs(z) < 3), np.round(z, 2)


@pytest.mark.slow
def test_outlier_view_is_flagged_and_can_be_dropped():
    views = rendered_views(PINHOLE, CHECKERBOARD, 12, seed=5)
    bad = views[4]
    noisy = bad.detection.corners_px + np.random.default_rng(0).normal(0, 1.5, bad.detection.corners_px.shape)
    views[4] = View(bad.name, Detection(noisy, bad.detection.ids, bad.detection.image_size,
                                              refined={name: noisy for name in bad.detection.refined}))

    kept = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size)
    flagged = [v.name for v in kept.views if v.outlier]
    assert flagged == [bad.name]
    assert all(v.used for v in kept.views)
    assert any(bad.name in w for w in kept.warnings)

    dropped = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size,
                                   replace(IntrinsicsSettings(), drop_outliers=True))
    assert [v.name for v in dropped.views if not v.used] == [bad.name]
    assert dropped.rms_px < kept.rms_px / 3
    excluded = next(v for v in dropped.views if v.name == bad.name)
    assert excluded.rms_px > 1.0  # still reported against the re-solved model
    assert abs(dropped.camera.K[0, 0] - 900.0) < abs(kept.camera.K[0, 0] - 900.0) + 0.5
