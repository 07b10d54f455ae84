"""LiDAR odometry for calibration: each scan registered by GICP (small_gicp) to a keyframe, the poses chained from the
first scan.

A calibration motion turns the rig in place, so most scans overlap the first one: each scan is registered to the
current keyframe (the first scan at the start), starting from the previous scan's pose, and a scan that shares less
than :data:`MIN_KEYFRAME_OVERLAP` of its points with the keyframe becomes the next keyframe. Registering to a fixed
keyframe, rather than scan to scan, keeps the errors from adding up: on the simulated turning rig the positions of a
LiDAR that did not move wandered by 10-17 mm (1σ) chained scan to scan and by 0.5-1.8 mm against the keyframe, and the
lever arm, which reads the LiDAR's own acceleration from them, moved from 11 mm off to 3 mm.
"""

from __future__ import annotations

import numpy as np

from backend.core.result import ProgressCallback, no_progress

VOXEL_M = 0.15
"""Downsampling before registration (m): the yard's walls and boxes stay, the work is bounded (at 0.25 m a tilted
LiDAR's height wandered by 6 cm on the simulated turning rig, at 0.15 m by 4 mm)."""
MAX_CORRESPONDENCE_M = 0.3
"""Farthest match (m): each scan starts from the previous one's pose, a few centimetres away at most."""
MIN_KEYFRAME_OVERLAP = 0.5
"""Share of a scan's points with a correspondence in the keyframe below which it becomes the next keyframe."""


def scan_poses(scans: list[np.ndarray], progress: ProgressCallback = no_progress) -> tuple[np.ndarray, np.ndarray]:
    """``T_first_scan`` (K, 4, 4; m) of every scan (points (N, 3) m in the LiDAR frame) by GICP against the
    keyframe, and each registration's inlier RMSE (m; the first 0)."""
    import small_gicp

    def prepared(points: np.ndarray):
        return small_gicp.preprocess_points(np.asarray(points, float), downsampling_resolution=VOXEL_M,
                                            num_threads=1)

    keyframe, T_first_keyframe = prepared(scans[0]), np.eye(4)
    poses, errors = [np.eye(4)], [0.0]
    T_keyframe_current = np.eye(4)
    for index, points in enumerate(scans[1:], start=1):
        progress(index / len(scans), f"registering scan {index + 1} of {len(scans)}")
        current = prepared(points)
        result = small_gicp.align(keyframe[0], current[0], keyframe[1], init_T_target_source=T_keyframe_current,
                                  registration_type="GICP", max_correspondence_distance=MAX_CORRESPONDENCE_M,
                                  num_threads=1)
        T_keyframe_current = np.asarray(result.T_target_source)
        poses.append(T_first_keyframe @ T_keyframe_current)
        errors.append(float(np.sqrt(result.error / max(result.num_inliers, 1))))
        if result.num_inliers < MIN_KEYFRAME_OVERLAP * current[0].size():
            keyframe, T_first_keyframe, T_keyframe_current = current, poses[-1], np.eye(4)
    return np.array(poses), np.array(errors)
