"""LiDAR-IMU calibration as the CLI, the API and the studio call it: scans from a folder of clouds named by their
time stamps (the CLI) or the LiDAR's captures in the session (the API and the studio), IMU samples from a CSV file;
in a session the result is kept with the IMU CSV beside it and accepted as the rig's LiDAR-IMU edge (the rotation;
the translation stays the mounting guess) and the IMU's clock offset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.calib._session import check_imu, check_lidar
from backend.calib.lidar_imu.solver import KIND, solve_lidar_imu
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.result import ProgressCallback, TransformResult, no_progress
from backend.devices.cloud_files import CLOUD_EXTENSIONS, read_cloud
from backend.devices.file_sequence import stamped_files
from backend.devices.imu_csv import parse_imu_csv
from backend.devices.imu_files import read_imu
from backend.store.session import Session

MAX_SCANS = 3000
"""Most scans one solve registers (five minutes at 10 Hz): the odometry's work is bounded before it is spent."""


def read_scan_folder(folder: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """Scan times (s) and points (N, 3; m, the LiDAR's frame) of every cloud file in ``folder``, each named by its
    time stamp in ns (``1403715273262142976.pcd``), in time order; :class:`InputError` naming the folder or file."""
    stamped = stamped_files(folder, CLOUD_EXTENSIONS, "scan", "clouds", "--scans", MAX_SCANS)
    return np.array([stamp_ns * 1e-9 for stamp_ns, _ in stamped]), [read_cloud(path).points for _, path in stamped]


def solve_files(scans: Path, imu_path: Path, progress: ProgressCallback = no_progress,
                imu_topic: str | None = None) -> TransformResult:
    """:func:`~backend.calib.lidar_imu.solver.solve_lidar_imu` on a folder of scans and the IMU's samples (a CSV, a
    ``.lvx`` recording, or a bag's ``imu_topic``: :func:`~backend.devices.imu_files.read_imu`)."""
    imu, warnings = read_imu(imu_path, imu_topic)
    times, points = read_scan_folder(scans)
    result = solve_lidar_imu(times, points, imu, progress)
    result.warnings.extend(warnings)
    return result


def summary(result: TransformResult) -> dict:
    """The ``lidar-imu`` command's JSON: ``T_lidar_imu`` (where the motion does not determine the translation: zero,
    its sigma null), the time offset (``t_imu = t_lidar + offset``) and their sigmas, the residuals, the verdict."""
    diagnostics = result.diagnostics
    return {"T_lidar_imu": result.T_parent_child.tolist(), "time_offset_s": diagnostics["time_offset_s"],
            "std": result.std | {"time_s": diagnostics["time_offset_std_s"]}, "residuals": dict(result.residuals),
            "rate_rms_rad_s": diagnostics["rate_rms_rad_s"], "verdict": result.verdict.to_dict(),
            "warnings": list(result.warnings), "seconds": result.seconds}


def read_session_inputs(session: Session, imu_sensor: str, lidar: str, imu_csv: tuple[str, bytes]
                        ) -> tuple[tuple[ImuSamples, list[str]], list[str]]:
    """The checked IMU samples of an upload (``(file name, bytes)``) and the ids of the LiDAR's captures, oldest
    first (before any work is queued); :class:`InputError` naming the sensor or the file."""
    check_imu(session, imu_sensor)
    check_lidar(session, lidar)
    imu = parse_imu_csv(imu_csv[1], imu_csv[0])
    captures = sorted(session.captures(lidar), key=lambda c: c.timestamp_s)
    if len(captures) > MAX_SCANS:
        raise InputError(f"{lidar} holds {len(captures)} scans; a LiDAR-IMU solve registers at most {MAX_SCANS}",
                         lidar)
    return imu, [c.id for c in captures]


def solve_session(session: Session, imu_sensor: str, lidar: str, imu_csv: tuple[str, bytes],
                  progress: ProgressCallback = no_progress) -> str:
    """Solve ``T_lidar_imu`` (rotation) and the time offset from the LiDAR's captures (taken while the rig turned in
    a static scene) and an uploaded IMU CSV, and keep the result with the CSV beside it; returns its id."""
    (imu, warnings), capture_ids = read_session_inputs(session, imu_sensor, lidar, imu_csv)
    captures = {c.id: c for c in session.captures(lidar)}
    times = np.array([captures[i].timestamp_s for i in capture_ids])
    scans = [session.capture_cloud(lidar, i)[0] for i in capture_ids]
    result = solve_lidar_imu(times, scans, imu, progress).named(lidar, imu_sensor)
    result.warnings.extend(warnings)
    record = result.to_record() | {"sources": {"imu": imu_csv[0], "scans": capture_ids}}
    return session.add_result(imu_sensor, record, inputs=[imu_csv[0], *capture_ids], files={"imu.csv": imu_csv[1]})


def lidar_imu_results(session: Session, imu_sensor: str) -> list[dict]:
    """The IMU's stored LiDAR-IMU results, oldest first, as :func:`summary` gives each (with its id and LiDAR)."""
    check_imu(session, imu_sensor)
    return [{"result_id": record["id"], "lidar": record["parent"]} | summary(TransformResult.from_record(record))
            for record in session.results(imu_sensor, KIND)]
