#!/usr/bin/env python
"""Camera-IMU benchmark on the real EuRoC MAV calibration recording (``shared/data/euroc_camera_imu``).

Figures: our solve's time (the fit alone, and with its cross-checks: the two halves and the other IMU model) and its
distance from two references, with each of Kalibr's two IMU models we fit (``calibrated``, ``scale-misalignment``):
EuRoC's own calibration (Kalibr, the set's README) and Basalt's independent calibration of the same sensor
(``VladyslavUsenko/basalt`` ``data/euroc_ds_calib.json``; its rotation belongs to its double-sphere lens, so only its
translation is compared). The in-run baseline is the angular-rate alignment alone (the offset by correlating angular
speeds, the rotation by Kabsch: what a rotation-only hand-eye method gives, and our solve's start): its time and its
rotation's distance from EuRoC's, as ratios. Kalibr's own run time on this sequence is not published, so no time is
set beside ours.

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/camera_imu.py
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
from bench_util import log, peak_rss_mb
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.observations import board_poses, read_detections_csv
from backend.calib.camera_imu.service import solve_files
from backend.calib.camera_imu.solver import CameraImuSettings, solve_camera_imu
from backend.calib.camera_imu.time_offset import align_rates, rates_from_rotations
from backend.core.transforms import invert
from backend.devices.imu_csv import read_imu_csv
from backend.exports.ros_camera_info import load_camera_info

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.calib.camera_imu.test_real import EUROC, T_IMU_CAM_BASALT, T_IMU_CAM_EUROC  # noqa: E402

BOARD = "aprilgrid:6x6:0.088:0.3"


def distances(T_cam_imu):
    T_imu_cam = invert(T_cam_imu)
    rotation_deg = np.degrees(Rotation.from_matrix(T_imu_cam[:3, :3].T @ T_IMU_CAM_EUROC[:3, :3]).magnitude())
    return {"from_euroc_mm": 1e3 * float(np.linalg.norm(T_imu_cam[:3, 3] - T_IMU_CAM_EUROC[:3, 3])),
            "from_euroc_deg": float(rotation_deg),
            "from_basalt_mm": 1e3 * float(np.linalg.norm(T_imu_cam[:3, 3] - T_IMU_CAM_BASALT[:3, 3]))}


def main():
    camera, _ = load_camera_info(EUROC / "camera.yaml")
    imu, _ = read_imu_csv(EUROC / "imu.csv")
    observations = read_detections_csv(EUROC / "detections.csv")

    log("baseline: angular-rate alignment alone")
    started = time.perf_counter()
    poses, rms = board_poses(camera, observations)
    ok = np.isfinite(rms)
    rate_t, rates = rates_from_rotations(observations.t_s[ok], np.transpose(poses[ok][:, :3, :3], (0, 2, 1)), 0.12)
    alignment = align_rates(imu.t_s, imu.gyro_rad_s, rate_t, rates)
    baseline_s = time.perf_counter() - started
    baseline_deg = float(np.degrees(Rotation.from_matrix(alignment.R_a_b.T @ T_IMU_CAM_EUROC[:3, :3]).magnitude()))

    log("ours: the fit alone")
    started = time.perf_counter()
    fit = solve_camera_imu(camera, observations, imu)
    fit_s = time.perf_counter() - started
    log("ours: the fit with the scale-misalignment IMU model")
    started = time.perf_counter()
    misaligned = solve_camera_imu(camera, observations, imu, CameraImuSettings(imu_model="scale-misalignment"))
    misaligned_s = time.perf_counter() - started
    log("ours: the fit with its cross-checks (two halves, the other IMU model) and verdict")
    started = time.perf_counter()
    result = solve_files(EUROC / "camera.yaml", EUROC / "detections.csv", EUROC / "imu.csv", BOARD)
    full_s = time.perf_counter() - started

    ours = distances(fit.T_cam_imu)
    print(json.dumps({
        "set": "euroc_camera_imu (EuRoC MAV imu_april, cam0 + ADIS16448, 72 s)",
        "ours": ours | {"time_offset_ms": 1e3 * fit.offset_s, "fit_s": fit_s, "with_cross_check_s": full_s,
                        "std_trans_mm": [1e3 * s for s in result.std["trans_m"]], "std_rot_deg": result.std["rot_deg"],
                        "verdict": result.verdict.level, "reprojection_px": fit.residual_rms["reprojection_px"],
                        "accel_rms_m_s2": fit.residual_rms["accel_m_s2"]},
        "ours_scale_misalignment": distances(misaligned.T_cam_imu) | {
            "time_offset_ms": 1e3 * misaligned.offset_s, "fit_s": misaligned_s,
            "accel_rms_m_s2": misaligned.residual_rms["accel_m_s2"],
            "imu_intrinsics": misaligned.imu_intrinsics.to_dict()},
        "euroc_vs_basalt_mm": 1e3 * float(np.linalg.norm(T_IMU_CAM_EUROC[:3, 3] - T_IMU_CAM_BASALT[:3, 3])),
        "baseline_rate_alignment": {"seconds": baseline_s, "from_euroc_deg": baseline_deg,
                                    "time_offset_ms": 1e3 * alignment.offset_s},
        "ratios": {"fit_s_over_baseline_s": fit_s / baseline_s,
                   "rotation_error_ours_over_baseline": ours["from_euroc_deg"] / baseline_deg},
        "kalibr": "no published run time or result on imu_april beside EuRoC's own calibration (the reference)",
        "peak_rss_mb": peak_rss_mb()}, indent=1))


if __name__ == "__main__":
    main()
