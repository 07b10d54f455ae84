"""The intrinsics problem's simulated scenes, rendered once per test process: the demo rig's mild lens
(``cam_front``) and its wide one (``cam_wide``) seeing the demo board, with each view's true corners."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.solver import View
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import transform_points
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig

BOARD = BoardSpec.parse(DEMO_BOARD)


def rendered(camera: str, count: int) -> tuple[CameraIntrinsics, list[View], list[np.ndarray]]:
    """The true camera, the detected views and each view's true corners (px, all ids) of ``count`` renders."""
    truth = demo_rig().get(camera).intrinsics
    rng = np.random.default_rng(0)
    views, true_corners = [], []
    for i, T in enumerate(board_poses(truth, BOARD, count, 0)):
        detection = detect_board(render_board_image(truth, BOARD, T, rng), BOARD)
        if detection is not None:
            views.append(View(f"{camera}{i:02d}", detection))
            true_corners.append(truth.project(transform_points(T, BOARD.object_points)))
    return truth, views, true_corners


@pytest.fixture(scope="session")
def mild() -> tuple[CameraIntrinsics, list[View], list[np.ndarray]]:
    """16 renders of the mild lens: (truth, views, true corners)."""
    return rendered("cam_front", 16)


@pytest.fixture(scope="session")
def wide() -> tuple[CameraIntrinsics, list[View], list[np.ndarray]]:
    """12 renders of the wide lens: (truth, views, true corners)."""
    return rendered("cam_wide", 12)
