"""A carried board's normal over time, as a camera and as a LiDAR see it (:class:`~.signals.MotionSignal`).

The camera's comes from each frame's board pose (PnP on the detected corners through the camera's intrinsics). The
LiDAR's comes from each scan's board points: the LiDAR-camera target solve's own segmentation
(:func:`~backend.calib.lidar_camera.target.find_board_points`: a RANSAC plane facing the camera's board normal,
near where the current ``T_camera_lidar`` puts the plate) placed by the camera frame nearest in time, then the
least-squares normal of those points. The clocks are not yet lined up, so the region and the normal's allowance are
wide (:data:`REGION_MARGIN_M`, :data:`NORMAL_ALLOWANCE_DEG`): a board turning at 0.5 rad/s moves 14 deg in the
largest offset searched.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from backend.calib.board.detection import Detection
from backend.calib.board.pose import board_pose
from backend.calib.lidar_camera.target import LidarCameraTargetSettings, find_board_points
from backend.calib.time_offset.signals import MotionSignal, board_normal_signal, facing_normals
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress

REGION_MARGIN_M = 0.4
"""How far (m) around where the nearest camera frame puts the plate its points are looked for."""
NORMAL_ALLOWANCE_DEG = 35.0
"""Largest angle (deg) between the LiDAR plane's normal and the nearest camera frame's board normal."""
MIN_CORNERS = 8
"""Fewest detected corners for a frame's board pose to count."""


def camera_board_poses(camera: CameraIntrinsics, board: BoardSpec, t_s: np.ndarray,
                       detections: Sequence[Detection | None]) -> tuple[np.ndarray, np.ndarray]:
    """The frames' times (s) and ``T_camera_board`` (K, 4, 4, m) where the board was found and PnP succeeded."""
    times, poses = [], []
    for t, detection in zip(t_s, detections, strict=True):
        if detection is None or len(detection.ids) < MIN_CORNERS:
            continue
        T = board_pose(camera, board, detection)
        if T is not None and T[2, 3] > 0:
            times.append(t)
            poses.append(T)
    return np.asarray(times, float), np.asarray(poses, float).reshape(-1, 4, 4)


def camera_signal(sensor: str, camera: CameraIntrinsics, board: BoardSpec, t_s: np.ndarray,
                  detections: Sequence[Detection | None]) -> MotionSignal:
    """The board's normal in the camera's frame, frame by frame."""
    times, poses = camera_board_poses(camera, board, t_s, detections)
    return board_normal_signal(sensor, times, poses)


def lidar_signal(sensor: str, board: BoardSpec, scan_t_s: np.ndarray, scans: Sequence[np.ndarray],
                 camera_t_s: np.ndarray, T_camera_boards: np.ndarray, T_camera_lidar: np.ndarray,
                 progress: ProgressCallback = no_progress) -> MotionSignal:
    """The board's normal in the LiDAR's frame, scan by scan (scans where the board is not found are skipped)."""
    settings = LidarCameraTargetSettings(max_normal_angle_deg=NORMAL_ALLOWANCE_DEG)
    rng = np.random.default_rng(0)
    times, normals, centres = [], [], []
    for k, (t, points) in enumerate(zip(scan_t_s, scans, strict=True)):
        if k % 20 == 0:
            progress(k / len(scans), f"finding the board in scan {k + 1} of {len(scans)}")
        nearest = int(np.argmin(np.abs(camera_t_s - t)))
        try:
            found = find_board_points(np.asarray(points, float)[:, :3], T_camera_boards[nearest], T_camera_lidar,
                                      board, REGION_MARGIN_M, settings, rng, f"scan {k}")
        except InputError:
            continue
        face = found.plane
        centre = face.mean(axis=0)
        normals.append(np.linalg.svd(face - centre, full_matrices=False)[2][2])
        centres.append(centre)
        times.append(t)
    progress(1.0, f"the board found in {len(times)} of {len(scans)} scans")
    return MotionSignal(sensor, "directions", np.asarray(times, float),
                        facing_normals(np.asarray(normals).reshape(-1, 3), np.asarray(centres).reshape(-1, 3)))
