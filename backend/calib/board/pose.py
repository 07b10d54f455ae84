"""The pose of a detected board in the camera's optical frame, for any camera model."""

from __future__ import annotations

import cv2
import numpy as np

from backend.calib.board.detection import Detection
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import from_rvec_tvec

NOMINAL_FOCAL_PER_WIDTH = 0.9
"""Focal length guess (px per px of image width, about 58 deg across) for a camera not yet calibrated."""


def nominal_camera(width: int, height: int) -> CameraIntrinsics:
    """A distortion-free pinhole guess, good enough to place a board roughly in 3D before calibrating."""
    f = NOMINAL_FOCAL_PER_WIDTH * width
    return CameraIntrinsics("pinhole-radtan", width, height, np.array([[f, 0, width / 2], [0, f, height / 2],
                                                                       [0, 0, 1.0]]))


def board_pose(camera: CameraIntrinsics, board: BoardSpec, detection: Detection) -> np.ndarray | None:
    """``T_camera_board`` (m) by PnP on undistorted corners, so fisheye and pinhole alike; None if PnP fails."""
    return pnp_pose(camera, detection.object_points(board), detection.corners_px)


def pnp_pose(camera: CameraIntrinsics, points: np.ndarray, pixels_px: np.ndarray) -> np.ndarray | None:
    """``T_camera_points`` (m): the pose of (N, 3) ``points`` (m, their own frame) seen at (N, 2) ``pixels_px``, by
    PnP on the undistorted pixels, so fisheye and pinhole alike; None if PnP fails."""
    ok, rvec, tvec = cv2.solvePnP(np.ascontiguousarray(points), camera.undistort_points(pixels_px), np.eye(3), None)
    return from_rvec_tvec(rvec, tvec) if ok else None
