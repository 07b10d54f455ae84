"""Board detection on simulated thermal images: weak and inverted contrast, temperature gradients, 16-bit counts.

Each case first shows that the plain detector (no fallbacks) misses the board, then
that :func:`detect_board` finds it, names the treatment, and puts the corners close
to the simulator's ground truth in the image's own pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from backend.calib.board.detection import FALLBACKS, Detection, detect_board
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import make_T, transform_points
from backend.plots.board import draw_detection
from backend.sim.board_motion import board_poses, project_corners
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD
from backend.sim.thermal import thermal_image

THERMAL_CAMERA = CameraIntrinsics("pinhole-radtan", 640, 512,
                                  np.array([[686.0, 0, 319.5], [0, 686.0, 255.5], [0, 0, 1]]), [-0.08, 0.02, 0, 0, 0])
"""A 640x512 LWIR camera with a 50 deg horizontal field of view, like common uncooled microbolometer cores."""
CHECKERBOARD = BoardSpec.parse(DEMO_BOARD)
CHARUCO = BoardSpec.parse("charuco:7x5:0.06:0.045:DICT_4X4_50")
WEAK_GRADIENT = {"contrast": 10.0, "gradient": 60.0}
"""About 6 grey levels between squares under a ramp of up to 60 levels: the plain detector misses every view."""
RAW_COUNTS = {"bit_depth": 16, "offset": 8000.0, "contrast": 400.0, "gradient": 300.0, "noise_sigma": 4.0}
"""uint16 raw counts: about 250 counts between squares on an 8000-count pedestal."""
CHECKERBOARD_RMS_PX = 0.5
"""Corner tolerance (RMS px) for thermal checkerboards; measured 0.21-0.29 px here, 0.14-0.45 px over 30 more views."""
CHARUCO_RMS_PX = 0.8
"""Corner tolerance (RMS px) for thermal ChArUco; measured 0.30-0.47 px here, up to 0.57 px over 6 more views
(visible: 0.07 px); its corner refinement suffers more from the noise than the checkerboard detector's fit."""


@dataclass(frozen=True)
class View:
    """A rendered visible view and its truth."""

    visible: np.ndarray
    T_camera_board: np.ndarray
    truth_px: np.ndarray
    """(N, 2) true corner pixels in ``BoardSpec.object_points`` order."""


def render_views(board: BoardSpec, count: int, seed: int) -> list[View]:
    """``count`` visible views of ``board`` in :data:`THERMAL_CAMERA`, filling 35-65 % of the image width."""
    views = []
    for i, T in enumerate(board_poses(THERMAL_CAMERA, board, count, seed=seed, fill=(0.35, 0.65))):
        visible = render_board_image(THERMAL_CAMERA, board, T, np.random.default_rng([seed, i]))
        views.append(View(visible, T, project_corners(THERMAL_CAMERA, board, T)))
    return views


@pytest.fixture(scope="module")
def checkerboard_views() -> list[View]:
    return render_views(CHECKERBOARD, 3, seed=1)


@pytest.fixture(scope="module")
def charuco_views() -> list[View]:
    return render_views(CHARUCO, 3, seed=2)


def thermal(view: View, index: int, **settings) -> np.ndarray:
    """The thermal image of ``view`` (inverted unless told), with noise seeded by ``index``."""
    return thermal_image(view.visible, np.random.default_rng([7, index]), **settings)


def plain_detect(image: np.ndarray, board: BoardSpec, live: bool = False) -> Detection | None:
    """What ``detect_board`` finds without any fallback treatment."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(FALLBACKS, (board.kind, live), ())
        return detect_board(image, board, live=live)


def rms_px(detection: Detection, board: BoardSpec, truth_px: np.ndarray) -> float:
    """RMS corner error (px) against the truth; a checkerboard may be numbered from either end (half turn)."""
    orders = [detection.corners_px]
    if board.kind == "checkerboard":
        orders.append(detection.corners_px[::-1])
    return min(float(np.sqrt(np.mean(np.sum((c - truth_px[detection.ids]) ** 2, axis=1)))) for c in orders)


def square_levels(image: np.ndarray, board: BoardSpec, T_camera_board: np.ndarray) -> tuple[float, float]:
    """Median image level at the centres of the visibly black and of the visibly white checkerboard squares."""
    cols, rows = board.cols + 1, board.rows + 1
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)
    centres_m = np.column_stack([(grid + 0.5) * board.square_m + board.outer_origin_m[:2], np.zeros(len(grid))])
    px = np.rint(THERMAL_CAMERA.project(transform_points(T_camera_board, centres_m))).astype(int)
    levels = image[px[:, 1], px[:, 0]].astype(float)
    black = grid.sum(axis=1) % 2 == 0  # as BoardSpec.render draws it: the top-left square is black
    return float(np.median(levels[black])), float(np.median(levels[~black]))


@pytest.mark.parametrize("inverted", [True, False])
def test_simulated_thermal_contrast_is_weak_and_inverted(checkerboard_views, inverted):
    view = checkerboard_views[0]
    image = thermal(view, 0, inverted=inverted, contrast=16.0, gradient=0.0)
    black, white = square_levels(image, CHECKERBOARD, view.T_camera_board)
    visible_black, visible_white = square_levels(view.visible, CHECKERBOARD, view.T_camera_board)
    assert visible_white - visible_black > 100
    assert 8 <= abs(black - white) <= 12  # grey levels between squares
    assert (black > white) == inverted


@pytest.mark.parametrize("inverted", [True, False], ids=["white-hot", "black-hot"])
@pytest.mark.slow
def test_weak_contrast_under_gradient_needs_clahe(checkerboard_views, inverted):
    for i, view in enumerate(checkerboard_views):
        image = thermal(view, i, inverted=inverted, **WEAK_GRADIENT)
        assert plain_detect(image, CHECKERBOARD) is None
        detection = detect_board(image, CHECKERBOARD)
        assert detection is not None, f"view {i}"
        assert detection.preprocessing == "normalised+clahe"
        assert len(detection.ids) == CHECKERBOARD.n_corners
        assert detection.image_size == (THERMAL_CAMERA.width, THERMAL_CAMERA.height)
        assert rms_px(detection, CHECKERBOARD, view.truth_px) < CHECKERBOARD_RMS_PX


def test_live_preview_finds_the_weak_board(checkerboard_views):
    image = thermal(checkerboard_views[0], 0, **WEAK_GRADIENT)
    assert plain_detect(image, CHECKERBOARD, live=True) is None
    detection = detect_board(image, CHECKERBOARD, live=True)
    assert detection is not None and detection.preprocessing == "normalised+clahe"
    assert rms_px(detection, CHECKERBOARD, checkerboard_views[0].truth_px) < CHECKERBOARD_RMS_PX


def test_16_bit_raw_counts(checkerboard_views):
    for i, view in enumerate(checkerboard_views[:2]):
        image = thermal(view, i, **RAW_COUNTS)
        assert image.dtype == np.uint16 and image.max() > 255
        with pytest.raises(cv2.error):  # OpenCV's detectors take 8-bit images only
            cv2.findChessboardCornersSB(image, CHECKERBOARD.corner_grid)
        detection = detect_board(image, CHECKERBOARD)
        assert detection is not None, f"view {i}"
        assert detection.preprocessing == "normalised+clahe"
        assert rms_px(detection, CHECKERBOARD, view.truth_px) < CHECKERBOARD_RMS_PX
    drawn = draw_detection(image, CHECKERBOARD, detection)
    assert drawn.dtype == np.uint8 and drawn.shape == (*image.shape, 3) and drawn.std() > 10


@pytest.mark.parametrize("live", [False, True], ids=["capture", "live"])
def test_inverted_charuco(charuco_views, live):
    for i, view in enumerate(charuco_views):
        image = thermal(view, i, contrast=24.0)
        assert plain_detect(image, CHARUCO, live=live) is None
        detection = detect_board(image, CHARUCO, live=live)
        assert detection is not None, f"view {i}"
        assert "inverted" in detection.preprocessing
        assert len(detection.ids) >= 8  # of 24 inner corners; measured 13-20
        assert rms_px(detection, CHARUCO, view.truth_px) < CHARUCO_RMS_PX


@pytest.mark.parametrize("board", [CHECKERBOARD, CHARUCO], ids=["checkerboard", "charuco"])
def test_visible_images_take_the_fast_path(checkerboard_views, charuco_views, board):
    view = (checkerboard_views if board.kind == "checkerboard" else charuco_views)[0]
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(FALLBACKS, (board.kind, False), ("no-such-treatment",))  # a fallback would raise KeyError
        detection = detect_board(view.visible, board)
    assert detection is not None and detection.preprocessing == "none"
    assert rms_px(detection, board, view.truth_px) < 0.15
    assert detect_board(cv2.cvtColor(view.visible, cv2.COLOR_GRAY2BGR), board).preprocessing == "none"


@pytest.mark.parametrize("board", [CHECKERBOARD, CHARUCO], ids=["checkerboard", "charuco"])
@pytest.mark.slow
def test_no_board_no_detection(board):
    behind_camera = make_T(np.eye(3), np.array([0.0, 0.0, -1.0]))  # not drawn: only the background
    visible = render_board_image(THERMAL_CAMERA, board, behind_camera, np.random.default_rng(3))
    empty = View(visible, behind_camera, np.zeros((0, 2)))
    for image in (visible, thermal(empty, 0, **WEAK_GRADIENT), thermal(empty, 1, **RAW_COUNTS)):
        assert detect_board(image, board) is None


def test_detection_dict_round_trip_and_old_dicts():
    detection = Detection(np.array([[1.5, 2.25], [3.0, 4.0]]), np.array([0, 1]), (640, 512), "normalised+inverted")
    again = Detection.from_dict(detection.to_dict())
    assert again.preprocessing == "normalised+inverted"
    np.testing.assert_array_equal(again.corners_px, detection.corners_px)
    old = {"corners_px": [[1.5, 2.25], [3.0, 4.0]], "ids": [0, 1], "image_size": [640, 512]}
    loaded = Detection.from_dict(old)
    assert loaded.preprocessing == "none" and loaded.image_size == (640, 512)
