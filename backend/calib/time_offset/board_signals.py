"""A carried board's normal over time, as a camera and as a LiDAR see it (:class:`~.signals.MotionSignal`), and the
board's points in each scan (:func:`board_in_scans`, a 2D scanner's too: :mod:`.scan_line`).

The camera's comes from each frame's board pose (PnP on the detected corners through the camera's intrinsics). The
LiDAR's comes from each scan's board points: the LiDAR-camera target solve's own segmentation
(:func:`~backend.calib.lidar_camera.target.find_board_points`: a RANSAC plane facing the camera's board normal,
near where the current ``T_camera_lidar`` puts the plate) placed by the camera frame nearest in time, then the
least-squares normal of those points (a face spreading wider than the board is skipped: :data:`MAX_SPREAD_RATIO`).
The clocks are not yet lined up, so the region and the normal's allowance are
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
MAX_SPREAD_RATIO = 1.3
"""A LiDAR's board face whose points spread (RMS, along their widest direction) more than this times the printed
board's widest spread (``sqrt((w² + h²) / 12)``, a uniformly covered rectangle's) took in more than the board (its
post, the ground or a wall beside it, nearly in its plane); that plane's normal would mislead by 15-30 deg, as seen
on the demo's board carried low past a 16-beam LiDAR, so the scan is skipped."""
MIN_CORNERS = 8
"""Fewest detected corners for a frame's board pose to count."""
MIN_LINE_POINTS = 12
"""Fewest points on a 2D scanner's board line for the scan to count (16 cm of board at 3 m in 0.25 deg steps): a
shorter segment's direction is too loose to time a turn by."""


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


def board_in_scans(board: BoardSpec, scan_t_s: np.ndarray, scans: Sequence[np.ndarray], camera_t_s: np.ndarray,
                   T_camera_boards: np.ndarray, T_camera_lidar: np.ndarray,
                   progress: ProgressCallback = no_progress) -> list[tuple[int, int, np.ndarray]]:
    """Per scan where the board was found: the scan's index, the nearest camera frame's index (on the clocks as they
    stand) and the board's points (N, 3, m, LiDAR frame): a 3D LiDAR's plane inliers, a 2D scanner's line inliers
    (its points all z = 0: a RANSAC line in the scan plane, at least :data:`MIN_LINE_POINTS`)."""
    settings = LidarCameraTargetSettings(max_normal_angle_deg=NORMAL_ALLOWANCE_DEG, min_line_points=MIN_LINE_POINTS)
    rng = np.random.default_rng(0)
    found = []
    for k, (t, points) in enumerate(zip(scan_t_s, scans, strict=True)):
        if k % 20 == 0:
            progress(k / len(scans), f"finding the board in scan {k + 1} of {len(scans)}")
        nearest = int(np.argmin(np.abs(camera_t_s - t)))
        try:
            board_points = find_board_points(np.asarray(points, float)[:, :3], T_camera_boards[nearest],
                                             T_camera_lidar, board, REGION_MARGIN_M, settings, rng, f"scan {k}")
        except InputError:
            continue
        found.append((k, nearest, board_points.plane))
    progress(1.0, f"the board found in {len(found)} of {len(scans)} scans")
    return found


def lidar_signal(sensor: str, board: BoardSpec, scan_t_s: np.ndarray, scans: Sequence[np.ndarray],
                 camera_t_s: np.ndarray, T_camera_boards: np.ndarray, T_camera_lidar: np.ndarray,
                 progress: ProgressCallback = no_progress) -> MotionSignal:
    """The board's normal in the LiDAR's frame, scan by scan (scans where the board is not found, or where its face
    took in more than the board, are skipped)."""
    found = board_in_scans(board, scan_t_s, scans, camera_t_s, T_camera_boards, T_camera_lidar, progress)
    largest_spread_m = MAX_SPREAD_RATIO * np.hypot(*board.size_m) / np.sqrt(12.0)
    times, normals, centres = [], [], []
    for k, _, face in found:
        centre = face.mean(axis=0)
        _, spreads, axes = np.linalg.svd(face - centre, full_matrices=False)
        if spreads[0] / np.sqrt(len(face)) <= largest_spread_m:
            times.append(scan_t_s[k])
            normals.append(axes[2])
            centres.append(centre)
    return MotionSignal(sensor, "directions", np.asarray(times, float),
                        facing_normals(np.asarray(normals).reshape(-1, 3), np.asarray(centres).reshape(-1, 3)))
