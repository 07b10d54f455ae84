"""Board pose by PnP against the simulator's ground truth, for pinhole and fisheye lenses."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.board.pose import board_pose, nominal_camera
from backend.core.boards import BoardSpec
from backend.core.transforms import invert, rotation_angle_deg
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from tests.calib.intrinsics.test_models import FISHEYE

BOARD = BoardSpec.parse(DEMO_BOARD)


def half_turn(board: BoardSpec) -> np.ndarray:
    """``T_board_turned``: the board turned 180 deg about its normal through its corner grid's centre.

    A checkerboard looks the same turned half-way round, so a detector may number
    its corners from either end; both poses are right.
    """
    cols, rows = board.corner_grid
    T = np.diag([-1.0, -1.0, 1.0, 1.0])
    T[:2, 3] = [(cols - 1) * board.square_m, (rows - 1) * board.square_m]
    return T


@pytest.mark.parametrize("camera", [demo_rig().get("cam_wide").intrinsics, FISHEYE], ids=["pinhole", "fisheye"])
@pytest.mark.slow
def test_pose_matches_ground_truth(camera):
    rng = np.random.default_rng(4)
    for T_true in board_poses(camera, BOARD, 4, seed=4):
        detection = detect_board(render_board_image(camera, BOARD, T_true, rng), BOARD)
        assert detection is not None
        T_found = board_pose(camera, BOARD, detection)
        T_error = min((invert(T_true @ T_turn) @ T_found for T_turn in (np.eye(4), half_turn(BOARD))),
                      key=lambda T: np.linalg.norm(T[:3, 3]))
        assert np.linalg.norm(T_error[:3, 3]) < 0.003  # metres, boards 0.5-2 m away
        assert rotation_angle_deg(T_error[:3, :3]) < 0.2


def test_nominal_camera_places_board_roughly():
    camera = demo_rig().get("cam_front").intrinsics
    T_true = board_poses(camera, BOARD, 1, seed=1)[0]
    detection = detect_board(render_board_image(camera, BOARD, T_true, np.random.default_rng(1)), BOARD)
    T_guess = board_pose(nominal_camera(camera.width, camera.height), BOARD, detection)
    distance_true, distance_guess = np.linalg.norm(T_true[:3, 3]), np.linalg.norm(T_guess[:3, 3])
    assert abs(distance_guess - distance_true) < 0.35 * distance_true
    assert T_guess[2, 3] > 0  # in front of the camera
