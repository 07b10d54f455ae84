"""AprilGrid detection on rendered views: most tags found, corners within 0.25 px of the truth, partial views kept."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.board.detection import detect_board
from backend.core.boards import BoardSpec
from backend.core.transforms import make_T
from backend.sim.board_renderer import render_board_image
from backend.sim.camera_imu import CAMERA

BOARD = BoardSpec.parse("aprilgrid:6x6:0.088:0.3")


@pytest.mark.parametrize(("euler_deg", "position_m", "least_tags"), [
    ([15, -10, 5], [-0.3, -0.25, 0.9], 25), ([0, 0, 0], [-0.3, -0.3, 0.7], 33), ([30, 20, 0], [-0.3, -0.3, 1.2], 25),
    ([-20, 25, 40], [-0.2, -0.4, 1.0], 25)])
def test_corners_are_found_where_the_board_is(euler_deg, position_m, least_tags) -> None:
    T = make_T(Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix(), position_m)
    image = render_board_image(CAMERA, BOARD, T, np.random.default_rng(0))
    found = detect_board(image, BOARD)
    assert found is not None and len(found.ids) >= 4 * least_tags - 4, None if found is None else len(found.ids)
    truth = CAMERA.project(BOARD.object_points[found.ids].astype(float) @ T[:3, :3].T + T[:3, 3])
    error = np.linalg.norm(truth - found.corners_px, axis=1)
    assert np.median(error) < 0.12 and error.max() < 0.25, (np.median(error), error.max())


def test_a_board_half_out_of_view_gives_the_tags_in_view() -> None:
    T = make_T(np.eye(3), [0.05, -0.3, 0.8])  # the left half of the grid off the image's left edge
    image = render_board_image(CAMERA, BOARD, T, np.random.default_rng(1))
    found = detect_board(image, BOARD)
    assert found is not None and 8 <= len(found.ids) < BOARD.n_corners
    truth = CAMERA.project(BOARD.object_points[found.ids].astype(float) @ T[:3, :3].T + T[:3, 3])
    assert (truth[:, 0] > 0).all() and np.linalg.norm(truth - found.corners_px, axis=1).max() < 0.4
