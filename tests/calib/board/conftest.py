"""The board problem's simulated scene, rendered and detected once per test process: each 720p lens of the demo
rig (``cam_front``, mild; ``cam_wide``, wide) sees the demo board in 8 poses tilted up to 50 degrees, then two
frames with the board behind the camera (the background alone), with the accurate detector's answer for every
frame, which the live detector is held to."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from backend.calib.board.detection import Detection, detect_board
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig

BOARD = BoardSpec.parse(DEMO_BOARD)
BEHIND_CAMERA = np.diag([1.0, 1.0, -1.0, 1.0])
"""A board pose behind the camera: the renderer draws the background alone."""


@dataclass(frozen=True)
class BoardScene:
    camera: CameraIntrinsics
    T_camera_boards: list[np.ndarray]
    """The true board poses (m) of the frames that show it."""
    images: list[np.ndarray]
    """One frame per pose, then two without the board."""
    accurate: list[Detection | None]
    """The accurate detector's answer for each frame."""


@pytest.fixture(scope="session", params=["cam_front", "cam_wide"])
def board_scene(request: pytest.FixtureRequest) -> BoardScene:
    camera = demo_rig().get(request.param).intrinsics
    rng = np.random.default_rng(3)
    poses = board_poses(camera, BOARD, 8, seed=11, max_tilt_deg=50)
    images = [render_board_image(camera, BOARD, T, rng) for T in [*poses, BEHIND_CAMERA, BEHIND_CAMERA]]
    return BoardScene(camera, poses, images, [detect_board(image, BOARD) for image in images])
