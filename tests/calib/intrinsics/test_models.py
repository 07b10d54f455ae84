"""Models and targets beyond the default: fisheye lenses, partial ChArUco views, outlier views."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from backend.calib.board.detection import Detection, detect_board
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.plots.intrinsics import residual_vectors
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from studio.wizard.intrinsics_step import parameters_markdown

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
    """A view whose every corner is 1.5 px off (the others 0.05 px) is noisier as a whole, not a few bad corners: no
    corner is rejected, it is flagged as an outlier view, and dropped on request."""
    views = rendered_views(PINHOLE, CHECKERBOARD, 12, seed=5)
    bad = views[4]
    noisy = bad.detection.corners_px + np.random.default_rng(0).normal(0, 1.5, bad.detection.corners_px.shape)
    views[4] = View(bad.name, Detection(noisy, bad.detection.ids, bad.detection.image_size,
                                              refined={name: noisy for name in bad.detection.refined}))

    kept = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size)
    assert kept.summary()["rejected_corners"] == 0
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


def test_single_bad_corners_are_rejected_and_listed_per_view():
    """Eight corners in four views moved by 2-4 px (a mis-detected corner, a speck of dust): each is rejected, named
    by view and id with where it was and how far off, and the lens comes back as from the clean corners."""
    views = rendered_views(PINHOLE, CHECKERBOARD, 12, seed=7)
    clean = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size, IntrinsicsSettings(jackknife=False))
    assert clean.summary()["rejected_corners"] == 0  # rendered corners: nothing beyond the noise
    assert np.abs(clean.camera.K - PINHOLE.K).max() < 0.3
    rng = np.random.default_rng(3)
    moved: dict[str, set[int]] = {}
    for index in (1, 4, 7, 10):
        view = views[index]
        picks = rng.choice(len(view.detection.ids), 2, replace=False)
        shift = np.zeros_like(view.detection.corners_px)
        shift[picks] = rng.uniform(2.0, 4.0, (2, 1)) * np.array([[0.6, 0.8]])
        corners = view.detection.corners_px + shift
        views[index] = View(view.name, Detection(corners, view.detection.ids, view.detection.image_size,
                                                 refined={name: corners for name in view.detection.refined}))
        moved[view.name] = set(view.detection.ids[picks].tolist())

    result = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size, IntrinsicsSettings(jackknife=False))
    found = {v.name: set(v.rejected.ids.tolist()) for v in result.views if v.rejected is not None}
    assert found == moved
    assert result.summary()["rejected_corners"] == 8 and result.summary()["views_dropped"] == []
    assert all(v.used for v in result.views)
    record = next(v for v in result.to_record()["views"] if v["image"] == views[1].name)["rejected"]
    assert record["view_dropped"] is False and len(record["corners_px"]) == len(record["residuals_px"]) == 2
    assert min(np.hypot(*np.array(record["residuals_px"]).T)) > 1.5
    rejected_px = np.vstack([v.rejected.corners_px for v in result.views if v.rejected is not None])
    used = [v for v in result.views if v.used]
    residuals = np.vstack([v.residuals_px for v in used])
    figure = residual_vectors(np.full_like(residuals, 100.0), residuals, np.zeros(len(residuals)), PINHOLE.image_size,
                              rejected_px)  # the report's plot marks them
    assert [t.get_text() for t in figure.axes[0].get_legend().get_texts()] == ["rejected (8)"]
    for marked in (rejected_px, None):  # the residuals by view are drawn with rejected corners or without
        plotted = residual_vectors(np.full_like(residuals, 100.0), residuals, np.zeros(len(residuals)),
                                   PINHOLE.image_size, marked).axes[1].collections[0].get_offsets()
        np.testing.assert_allclose(plotted, residuals)
    listed = ", ".join(f"{name} 2" for name in sorted(moved))  # and the studio's panel lists them
    assert f"Corners rejected as outliers: {listed}\n" in parameters_markdown(result.to_record())
    unrejected = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size,
                                      IntrinsicsSettings(jackknife=False, reject_corners=False))
    assert unrejected.rms_px > 2 * result.rms_px
    error_px, unrejected_error_px = (np.abs(r.camera.K - PINHOLE.K).max() for r in (result, unrejected))
    assert error_px < 0.3 and error_px < unrejected_error_px, (error_px, unrejected_error_px)


def test_a_view_that_would_lose_more_than_a_quarter_of_its_corners_is_dropped_and_named():
    """A third of one view's corners 3 px off every which way (glare across the board): rather than keep two thirds
    of a view, the view is dropped whole and named, and the others are solved as if it had not been taken. (A
    coherent shift of a view is another matter: its pose takes it up, every corner looks alike, and the view-level
    outlier flag speaks for it, as above.)"""
    views = rendered_views(PINHOLE, CHECKERBOARD, 12, seed=7)
    clean = calibrate_intrinsics(views[:3] + views[4:], CHECKERBOARD, PINHOLE.image_size,
                                 IntrinsicsSettings(jackknife=False))
    bad = views[3]
    corners = bad.detection.corners_px.copy()
    angles = np.random.default_rng(1).uniform(0.0, 2.0 * np.pi, len(corners[::3]))
    corners[::3] += 3.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    views[3] = View(bad.name, Detection(corners, bad.detection.ids, bad.detection.image_size,
                                        refined={name: corners for name in bad.detection.refined}))
    result = calibrate_intrinsics(views, CHECKERBOARD, PINHOLE.image_size, IntrinsicsSettings(jackknife=False))
    assert result.summary()["views_dropped"] == [bad.name]
    assert [v.name for v in result.views if not v.used] == [bad.name]
    assert f"{bad.name}: " in " ".join(result.warnings) and "the view was dropped" in " ".join(result.warnings)
    # the corner set (the detector's or a refinement) is chosen again without the dropped view, which first voted
    # for another one (refined-0.5 against refined-0.4)
    assert result.corners["chosen"] == clean.corners["chosen"] and "without the dropped" in result.corners["why"]
    np.testing.assert_allclose(result.camera.K, clean.camera.K, atol=1e-6)
