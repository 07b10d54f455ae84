"""Kalibr's AprilGrid as the LiDAR-camera target: its outline and plane in a simulated 16-beam LiDAR's scans and its
tags in rendered images (12 poses), solved by the target method to the true ``T_camera_lidar``."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.board.pose import board_pose
from backend.calib.lidar_camera.target import LidarCameraTargetSettings, TargetObservation, solve_target
from backend.core.boards import BoardSpec
from backend.core.transforms import apply_params, transform_error
from backend.sim.board_renderer import PLATE_MARGIN_SQUARES, render_board_image
from backend.sim.moving_board import CAMERA, T_CAMERA_LIDAR, board_pose_lidar, scan_plate, sector_rays

pytestmark = pytest.mark.slow

SPEC = "aprilgrid:6x6:0.088:0.3"


def test_the_target_method_solves_on_an_aprilgrid() -> None:
    board, rng = BoardSpec.parse(SPEC), np.random.default_rng(7)
    rays, _ = sector_rays()
    observations = []
    for k, T_lidar_board in enumerate(board_pose_lidar(np.linspace(0.0, 19.0, 12), seed=5, board=SPEC)):
        image = render_board_image(CAMERA, board, T_CAMERA_LIDAR @ T_lidar_board, rng)
        detection = detect_board(image, board)
        assert detection is not None, f"pose {k}: the AprilGrid was not detected"
        observations.append(TargetObservation(board_pose(CAMERA, board, detection),
                                              scan_plate(board, T_lidar_board, rays, rng, 0.01), f"pose {k}"))
    T_init = apply_params(T_CAMERA_LIDAR, np.array([0.05, -0.04, 0.03, 0.03, -0.02, 0.04]))
    settings = LidarCameraTargetSettings(plate_margin_m=PLATE_MARGIN_SQUARES * board.square_m)
    result = solve_target(board, observations, T_init, settings)
    trans_m, rot_deg = transform_error(result.T_parent_child, T_CAMERA_LIDAR)
    print(f"AprilGrid target: {1e3 * trans_m} mm, {np.linalg.norm(rot_deg):.3f} deg off, "
          f"sigma {result.std}")
    assert result.converged and np.linalg.norm(trans_m) < 5e-3 and np.linalg.norm(rot_deg) < 0.3, (trans_m, rot_deg)
    assert (np.abs(rot_deg) < 3 * np.array(result.std["rot_deg"])).all(), (rot_deg, result.std)
