"""LiDAR-IMU calibration as the CLI calls it: scans from a folder of clouds named by their time stamps, IMU samples
from a CSV file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.calib.lidar_imu.solver import solve_lidar_imu
from backend.core.result import ProgressCallback, TransformResult, no_progress
from backend.devices.cloud_files import CLOUD_EXTENSIONS, read_cloud
from backend.devices.file_sequence import stamped_files
from backend.devices.imu_csv import read_imu_csv

MAX_SCANS = 3000
"""Most scans one solve registers (five minutes at 10 Hz): the odometry's work is bounded before it is spent."""


def read_scan_folder(folder: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """Scan times (s) and points (N, 3; m, the LiDAR's frame) of every cloud file in ``folder``, each named by its
    time stamp in ns (``1403715273262142976.pcd``), in time order; :class:`InputError` naming the folder or file."""
    stamped = stamped_files(folder, CLOUD_EXTENSIONS, "scan", "clouds", "--scans", MAX_SCANS)
    return np.array([stamp_ns * 1e-9 for stamp_ns, _ in stamped]), [read_cloud(path).points for _, path in stamped]

def solve_files(scans: Path, imu_path: Path, progress: ProgressCallback = no_progress) -> TransformResult:
    """:func:`~backend.calib.lidar_imu.solver.solve_lidar_imu` on a folder of scans and an IMU CSV."""
    imu, warnings = read_imu_csv(imu_path)
    times, points = read_scan_folder(scans)
    result = solve_lidar_imu(times, points, imu, progress)
    result.warnings.extend(warnings)
    return result


def summary(result: TransformResult) -> dict:
    """The ``lidar-imu`` command's JSON: ``T_lidar_imu`` (translation not estimated: zero, its sigma null), the time
    offset (``t_imu = t_lidar + offset``) and their sigmas, the residuals, the verdict."""
    diagnostics = result.diagnostics
    return {"T_lidar_imu": result.T_parent_child.tolist(), "time_offset_s": diagnostics["time_offset_s"],
            "std": result.std | {"time_s": diagnostics["time_offset_std_s"]}, "residuals": dict(result.residuals),
            "rate_rms_rad_s": diagnostics["rate_rms_rad_s"], "verdict": result.verdict.to_dict(),
            "warnings": list(result.warnings), "seconds": result.seconds}
