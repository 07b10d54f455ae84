#!/usr/bin/env python
"""Time-offset benchmark on simulated recordings of a board carried through a camera's and a LiDAR's views
(``backend/sim/moving_board.py``: a 16-beam spinner at 10 Hz firing each shot at its own instant, a camera at 15 Hz,
37 ms apart), five seeds.

No real recording with a known camera-LiDAR offset is in ``shared/data`` (the VLP-16 set is 8 still poses), so this is
the simulator's figure only. The in-run baseline is the classic first step (Kalibr's ``findTimeshiftCameraImuPrior``
does it for a camera and an IMU): the normals' angular speeds by finite differences, cross-correlated, then Kabsch on
the rate vectors (:func:`~backend.calib.camera_imu.time_offset.align_rates`). Ours lines the normals themselves up
(:mod:`backend.calib.time_offset.alignment`). Figures: each one's offset error and time, as ratios.

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/time_offset.py
"""

import json
import time

import numpy as np
from bench_util import log, peak_rss_mb

from backend.calib.camera_imu.time_offset import align_rates
from backend.calib.time_offset.board_signals import camera_board_poses, camera_signal, lidar_signal
from backend.calib.time_offset.solver import solve_time_offset
from backend.sim.moving_board import simulate_moving_board

SEEDS = range(5)


def normal_rates(t_s, normals):
    """The normal's angular velocity perpendicular to it (rad/s), by finite differences, at the mid times."""
    steps = np.diff(t_s)
    rates = np.cross(normals[:-1], normals[1:]) / steps[:, None]
    keep = steps < 2.5 * np.median(steps)
    return (0.5 * (t_s[:-1] + t_s[1:]))[keep], rates[keep]


def main():
    rows = []
    for seed in SEEDS:
        log(f"seed {seed}")
        recording = simulate_moving_board(offset_s=0.037, seed=seed)
        times, poses = camera_board_poses(recording.camera, recording.board, recording.camera_t_s,
                                          recording.detections)
        camera = camera_signal("camera", recording.camera, recording.board, recording.camera_t_s,
                               recording.detections)
        lidar = lidar_signal("lidar", recording.board, recording.scan_t_s, recording.scans, times, poses,
                             recording.T_camera_lidar)
        started = time.perf_counter()
        ours = solve_time_offset(camera, lidar)
        ours_s = time.perf_counter() - started
        started = time.perf_counter()
        baseline = align_rates(*normal_rates(lidar.t_s, lidar.vectors), *normal_rates(camera.t_s, camera.vectors))
        baseline_s = time.perf_counter() - started
        rows.append({"seed": seed, "ours_error_ms": 1e3 * (ours.offset_s - recording.offset_s),
                     "ours_std_ms": 1e3 * ours.std_s, "ours_s": ours_s, "verdict": ours.verdict.level,
                     "baseline_error_ms": 1e3 * (baseline.offset_s - recording.offset_s), "baseline_s": baseline_s})
    ours_rms = float(np.sqrt(np.mean([r["ours_error_ms"] ** 2 for r in rows])))
    baseline_rms = float(np.sqrt(np.mean([r["baseline_error_ms"] ** 2 for r in rows])))
    print(json.dumps({
        "set": "simulated moving board (camera 15 Hz + 16-beam LiDAR 10 Hz, 20 s, 37 ms apart), seeds 0-4",
        "runs": rows,
        "ours": {"rms_error_ms": ours_rms, "median_s": float(np.median([r["ours_s"] for r in rows]))},
        "baseline_speed_correlation": {"rms_error_ms": baseline_rms,
                                       "median_s": float(np.median([r["baseline_s"] for r in rows]))},
        "ratios": {"error_ours_over_baseline": ours_rms / baseline_rms,
                   "time_ours_over_baseline": float(np.median([r["ours_s"] / r["baseline_s"] for r in rows]))},
        "real_data": "none: no shared recording holds a moving board seen by a camera and a LiDAR with a known offset",
        "peak_rss_mb": peak_rss_mb()}, indent=1))


if __name__ == "__main__":
    main()
