"""Stereo checks on OpenCV's real stereo chessboard pairs: epipolar errors, rectification, preview."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from backend.calib.multicam.stereo import (
    LINE_COLOUR_BGR,
    epipolar_errors,
    fundamental_matrix,
    rectified_preview,
    rectified_row_errors,
    rectify,
)
from backend.core.camera import UNDISTORT_CRITERIA, CameraIntrinsics
from backend.core.errors import InputError
from backend.core.transforms import invert, make_T

PATTERN = (9, 6)
"""Inner corners of the data set's chessboard (see its README); squares are 0.025 m."""
SQUARE_M = 0.025
SIZE = (640, 480)


@dataclass
class StereoPair:
    left: CameraIntrinsics
    right: CameraIntrinsics
    T_left_right: np.ndarray
    """Inverse of stereoCalibrate's (R, T), which map the first (left) camera into the second."""
    T_opencv: np.ndarray
    """stereoCalibrate's T (m)."""
    F: np.ndarray
    """stereoCalibrate's fundamental matrix."""
    left_px: np.ndarray
    """(13 * 54, 2) distorted corners in the left images."""
    right_px: np.ndarray
    images: tuple[np.ndarray, np.ndarray]
    """The first pair (gray)."""


def _corners(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Gray image and refined corners, as OpenCV's samples/python/calibrate.py finds them."""
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(gray, PATTERN)
    assert found, path
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    return gray, cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)


@pytest.fixture(scope="module")
def pair(stereo_chessboard: Path) -> StereoPair:
    """Each camera by calibrateCamera, then the pair by stereoCalibrate with the intrinsics fixed."""
    lefts = sorted(stereo_chessboard.glob("left*.jpg"))
    assert len(lefts) == 13
    board = np.zeros((PATTERN[0] * PATTERN[1], 3), np.float32)
    board[:, :2] = np.mgrid[0 : PATTERN[0], 0 : PATTERN[1]].T.reshape(-1, 2) * SQUARE_M
    found = {"left": [], "right": []}
    images = {}
    for left_path in lefts:
        right_path = left_path.with_name(left_path.name.replace("left", "right"))
        for side, path in (("left", left_path), ("right", right_path)):
            gray, corners = _corners(path)
            found[side].append(corners)
            images.setdefault(side, gray)
    objects = [board] * len(lefts)
    cameras = {}
    for side, corners in found.items():
        rms_px, K, dist, _, _ = cv2.calibrateCamera(objects, corners, SIZE, None, None)
        assert rms_px < 0.3, side
        cameras[side] = CameraIntrinsics("pinhole-radtan", *SIZE, K, dist)
    left, right = cameras["left"], cameras["right"]
    rms_px, _, _, _, _, R, T, _, F = cv2.stereoCalibrate(
        objects, found["left"], found["right"], left.K, left.dist, right.K, right.dist, SIZE,
        flags=cv2.CALIB_FIX_INTRINSIC)
    assert rms_px < 0.3
    return StereoPair(left, right, invert(make_T(R, T)), T.ravel(), F,
                      np.concatenate(found["left"]).reshape(-1, 2).astype(float),
                      np.concatenate(found["right"]).reshape(-1, 2).astype(float),
                      (images["left"], images["right"]))


def _opencv_sample_errors(pair: StereoPair, undistort) -> np.ndarray:
    """Per-point epipolar error of samples/cpp/stereo_calib.cpp: |d_left| + |d_right| via computeCorrespondEpilines."""
    points = []
    for px, camera in ((pair.left_px, pair.left), (pair.right_px, pair.right)):
        points.append(undistort(px.reshape(-1, 1, 2), camera.K, camera.dist))
    lines_in_right = cv2.computeCorrespondEpilines(points[0], 1, pair.F).reshape(-1, 3)
    lines_in_left = cv2.computeCorrespondEpilines(points[1], 2, pair.F).reshape(-1, 3)
    left, right = points[0].reshape(-1, 2), points[1].reshape(-1, 2)
    return (np.abs(np.sum(right * lines_in_right[:, :2], axis=1) + lines_in_right[:, 2])
            + np.abs(np.sum(left * lines_in_left[:, :2], axis=1) + lines_in_left[:, 2]))


def test_epipolar_errors_agree_with_opencv_sample(pair: StereoPair) -> None:
    errors = epipolar_errors(pair.left, pair.right, pair.T_left_right, pair.left_px, pair.right_px)
    assert errors.shape == (13 * 54,)
    rms_px = float(np.sqrt(np.mean(errors**2)))

    # the sample's computation with the same (converged) undistortion: same numbers, point by point
    converged = _opencv_sample_errors(
        pair, lambda px, K, D: cv2.undistortPointsIter(px, K, D, None, K, UNDISTORT_CRITERIA))
    assert rms_px == pytest.approx(float(np.sqrt(np.mean((converged / 2) ** 2))), abs=1e-6)
    np.testing.assert_allclose(errors, converged / 2, rtol=0, atol=1e-6)
    # literally the sample (5-iteration undistortPoints): within its undistortion error of ~1e-3 px
    sample = _opencv_sample_errors(pair, lambda px, K, D: cv2.undistortPoints(px, K, D, None, K))
    assert 2 * errors.mean() == pytest.approx(sample.mean(), abs=1e-3)

    # a good calibration: 0.18 px RMS, no corner beyond 1 px
    assert rms_px < 0.3
    assert errors.max() < 1.0

    # our F is stereoCalibrate's up to scale, which fixes the T_left_right direction
    F = fundamental_matrix(pair.left, pair.right, pair.T_left_right)
    F_cv = pair.F / np.linalg.norm(pair.F)
    np.testing.assert_allclose(F * np.sign(F.ravel() @ F_cv.ravel()), F_cv, atol=1e-9)
    # the inverse transform (OpenCV's R, T taken as T_left_right) is visibly wrong
    wrong = epipolar_errors(pair.left, pair.right, invert(pair.T_left_right), pair.left_px, pair.right_px)
    assert np.sqrt(np.mean(wrong**2)) > 10 * rms_px


def test_rectification(pair: StereoPair) -> None:
    rect = rectify(pair.left, pair.right, pair.T_left_right)
    assert rect.baseline_m == pytest.approx(float(np.linalg.norm(pair.T_opencv)), rel=1e-12)
    assert 0.07 < rect.baseline_m < 0.095  # about 3.3 squares, see the data set's README
    assert not rect.vertical
    # the rectified right camera sits baseline_m along +x: P2 = [f 0 cx -f*b; ...]
    assert -rect.P2[0, 3] / rect.P2[0, 0] == pytest.approx(rect.baseline_m, rel=1e-9)
    for R in (rect.R1, rect.R2):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    for map_ in (rect.left_map_x, rect.left_map_y, rect.right_map_x, rect.right_map_y):
        assert map_.shape == (480, 640) and map_.dtype == np.float32

    rows = rectified_row_errors(rect, pair.left_px, pair.right_px)
    assert rows.shape == (13 * 54,)
    assert rows.max() < 1.0
    assert np.sqrt(np.mean(rows**2)) < 0.3
    # the remap tables and the point mapping agree: the table at a rectified corner holds the distorted corner
    left_rect, _ = rect.rectify_points(pair.left_px, pair.right_px)
    inside = np.all((left_rect > 2) & (left_rect < np.array(SIZE) - 3), axis=1)
    u, v = left_rect[inside].T
    source = np.column_stack([cv2.remap(m, u.astype(np.float32).reshape(1, -1), v.astype(np.float32).reshape(1, -1),
                                        cv2.INTER_LINEAR).ravel() for m in (rect.left_map_x, rect.left_map_y)])
    assert np.max(np.linalg.norm(source - pair.left_px[inside], axis=1)) < 0.05


def test_preview(pair: StereoPair) -> None:
    rect = rectify(pair.left, pair.right, pair.T_left_right)
    left_image, right_image = pair.images
    preview = rectified_preview(rect, left_image, right_image, line_spacing_px=40)
    assert preview.shape == (480, 1280, 3) and preview.dtype == np.uint8
    green = np.all(preview == LINE_COLOUR_BGR, axis=2)
    line_rows = np.flatnonzero(green.all(axis=1))
    np.testing.assert_array_equal(line_rows, np.arange(0, 480, 40))
    # between the lines: the two rectified images themselves
    left_rect, right_rect = rect.rectify_images(left_image, right_image)
    np.testing.assert_array_equal(preview[1:40, :640, 0], left_rect[1:40])
    np.testing.assert_array_equal(preview[1:40, 640:, 1], right_rect[1:40])
    assert left_rect[200:280, 250:400].std() > 20  # the board is there, not a black image

    with pytest.raises(InputError, match="the right image is 320x240 px"):
        rectified_preview(rect, left_image, cv2.resize(right_image, (320, 240)))


def test_rectify_refuses_mismatched_cameras(pair: StereoPair) -> None:
    small = CameraIntrinsics("pinhole-radtan", 320, 240, pair.right.K / 2 + np.diag([0, 0, 0.5]), pair.right.dist)
    with pytest.raises(InputError, match="one image size"):
        rectify(pair.left, small, pair.T_left_right)
    fisheye = CameraIntrinsics("fisheye-equidistant", *SIZE, pair.right.K, np.zeros(4))
    with pytest.raises(InputError, match="one model"):
        rectify(pair.left, fisheye, pair.T_left_right)
    with pytest.raises(InputError, match="alpha"):
        rectify(pair.left, pair.right, pair.T_left_right, alpha=2)


def test_fisheye_pair_rectifies_rows() -> None:
    """A synthetic fisheye pair: points seen by both land on one rectified row, and epipolar errors vanish."""
    K = np.array([[300.0, 0.0, 320.0], [0.0, 300.0, 240.0], [0.0, 0.0, 1.0]])
    left = CameraIntrinsics("fisheye-equidistant", *SIZE, K, [0.02, -0.01, 0.003, -0.0005])
    right = CameraIntrinsics("fisheye-equidistant", *SIZE, K + np.diag([2.0, 2.0, 0.0]), [0.015, -0.008, 0.002, 0.0])
    T_left_right = make_T(cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0], [0.12, 0.002, -0.001])
    rng = np.random.default_rng(3)
    points_left = np.column_stack([rng.uniform(-1.0, 1.0, 200), rng.uniform(-0.7, 0.7, 200), rng.uniform(1.5, 4, 200)])
    points_right = (invert(T_left_right) @ np.column_stack([points_left, np.ones(200)]).T).T[:, :3]
    left_px, right_px = left.project(points_left), right.project(points_right)

    assert np.max(epipolar_errors(left, right, T_left_right, left_px, right_px)) < 1e-6
    rect = rectify(left, right, T_left_right)
    assert rect.baseline_m == pytest.approx(np.linalg.norm(T_left_right[:3, 3]), rel=1e-12)
    assert np.max(rectified_row_errors(rect, left_px, right_px)) < 1e-6
    shifted = right_px + [0.0, 2.0]  # two pixels off the epipolar line
    assert np.median(epipolar_errors(left, right, T_left_right, left_px, shifted)) > 0.5
