"""LiDAR odometry for calibration: each scan registered to the one before by GICP (small_gicp), the orientations
chained from the first scan."""

from __future__ import annotations

import numpy as np

from backend.core.result import ProgressCallback, no_progress

VOXEL_M = 0.25
"""Downsampling before registration (m): the yard's walls and boxes stay, the work is bounded."""
MAX_CORRESPONDENCE_M = 1.0


def scan_orientations(scans: list[np.ndarray], progress: ProgressCallback = no_progress
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``R_first_scan`` (K, 3, 3) of every scan (points (N, 3) m in the LiDAR frame) chained from scan-to-scan GICP,
    and each registration's inlier RMSE (m; the first 0)."""
    import small_gicp

    orientations = [np.eye(3)]
    errors = [0.0]
    previous = small_gicp.preprocess_points(np.asarray(scans[0], float), downsampling_resolution=VOXEL_M,
                                            num_threads=1)
    T_previous_current = np.eye(4)
    for index, points in enumerate(scans[1:], start=1):
        progress(index / len(scans), f"registering scan {index + 1} of {len(scans)}")
        current = small_gicp.preprocess_points(np.asarray(points, float), downsampling_resolution=VOXEL_M,
                                               num_threads=1)
        result = small_gicp.align(previous[0], current[0], previous[1], init_T_target_source=T_previous_current,
                                  registration_type="GICP", max_correspondence_distance=MAX_CORRESPONDENCE_M,
                                  num_threads=1)
        T_previous_current = np.asarray(result.T_target_source)
        orientations.append(orientations[-1] @ T_previous_current[:3, :3])
        errors.append(float(np.sqrt(result.error / max(result.num_inliers, 1))))
        previous = current
    return np.array(orientations), np.array(errors)
