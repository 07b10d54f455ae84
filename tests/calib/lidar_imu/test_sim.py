"""LiDAR-IMU rotation, time offset and translation on a simulated recording: the top LiDAR turned in the yard, an IMU
mounted upside down under it, 6-9 cm off its origin, with a 15 ms clock offset."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.lidar_imu.solver import solve_lidar_imu
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.devices.imu_csv import format_imu_csv
from backend.sim.lidar_imu import simulate_lidar_imu
from tests.conftest import cli_in_process

pytestmark = pytest.mark.slow


def test_rotation_offset_and_translation_within_tolerance_and_3_sigma() -> None:
    recording = simulate_lidar_imu(duration_s=12.0, offset_s=0.015)
    result = solve_lidar_imu(recording.scan_times_s, recording.scans, recording.imu)
    rotation_deg = np.degrees(Rotation.from_matrix(result.T_parent_child[:3, :3].T @ recording.R_lidar_imu)
                              .as_rotvec())
    offset_s = result.diagnostics["time_offset_s"]
    translation_m = result.T_parent_child[:3, 3] - recording.t_lidar_imu_m
    print(f"LiDAR-IMU: rotation {np.linalg.norm(rotation_deg):.3f} deg off, offset {1e3 * offset_s:.2f} ms "
          f"(truth 15), translation {1e3 * translation_m} mm off; sigma {result.std}, "
          f"{1e3 * result.diagnostics['time_offset_std_s']:.2f} ms")
    assert np.linalg.norm(rotation_deg) < 0.2, rotation_deg
    assert abs(offset_s - recording.offset_s) < 2e-3, offset_s
    assert (np.abs(rotation_deg) < 3 * np.array(result.std["rot_deg"]) + 0.02).all(), (rotation_deg, result.std)
    assert np.linalg.norm(translation_m) < 5e-3, translation_m
    assert (np.abs(translation_m) < 3 * np.array(result.std["trans_m"])).all(), (translation_m, result.std)
    assert result.diagnostics["lever_arm"]["determined"] and result.verdict.level == "trusted", result.verdict.reasons
    assert any("cross-check gravity" in r for r in result.verdict.reasons), result.verdict.reasons


def test_an_accelerometer_drowned_in_vibration_leaves_the_translation_undetermined() -> None:
    """With 3 m/s² of vibration on the accelerometer the lever arm's few tenths of m/s² are lost: the rotation and
    the offset still come, but the translation is not returned as a number, and the verdict says why."""
    recording = simulate_lidar_imu(duration_s=8.0, seed=4, accel_sigma=3.0)
    result = solve_lidar_imu(recording.scan_times_s, recording.scans, recording.imu)
    assert result.std["trans_m"] == [None, None, None] and not result.diagnostics["lever_arm"]["determined"]
    assert result.verdict.level == "check"
    assert any("translation is not determined by this motion" in r for r in result.verdict.reasons), \
        result.verdict.reasons


def test_a_rig_turned_about_one_axis_is_refused() -> None:
    still = simulate_lidar_imu(duration_s=3.0, amplitude_rad=0.01)
    with pytest.raises(InputError, match="needs the rig turned through at least 20|turned about its"):
        solve_lidar_imu(still.scan_times_s, still.scans, still.imu)


def test_the_command_reads_a_folder_of_scans(tmp_path) -> None:
    """``calib-studio lidar-imu --scans DIR --imu imu.csv --json`` on the simulated recording's files."""
    recording = simulate_lidar_imu(duration_s=8.0, offset_s=-0.02, seed=2)
    (tmp_path / "scans").mkdir()
    for t_s, points in zip(recording.scan_times_s, recording.scans, strict=True):
        np.save(tmp_path / "scans" / f"{round((1000 + t_s) * 1e9)}.npy", points)
    imu = ImuSamples(recording.imu.t_s + 1000, recording.imu.gyro_rad_s, recording.imu.accel_m_s2)
    (tmp_path / "imu.csv").write_bytes(format_imu_csv(imu))
    run = cli_in_process("lidar-imu", "--scans", tmp_path / "scans", "--imu", tmp_path / "imu.csv", "--json")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert abs(summary["time_offset_s"] + 0.02) < 2e-3, summary["time_offset_s"]
    rotation_deg = np.degrees(Rotation.from_matrix(np.array(summary["T_lidar_imu"])[:3, :3].T
                                                   @ recording.R_lidar_imu).magnitude())
    assert rotation_deg < 0.2 and max(summary["std"]["trans_m"]) < 0.01, summary["std"]
    (tmp_path / "scans" / "first.npy").write_bytes(b"")
    named = cli_in_process("lidar-imu", "--scans", tmp_path / "scans", "--imu", tmp_path / "imu.csv", "--json")
    assert named.returncode != 0 and "first.npy: expected the scan's time stamp in ns" in named.stderr
