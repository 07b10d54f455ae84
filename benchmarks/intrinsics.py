#!/usr/bin/env python
"""Intrinsic calibration benchmark: our solver and board detector against plain OpenCV.

What it measures, in one run on the same data:

- ``solve_s``: ``calibrate_intrinsics`` on 50 views with default settings, which
  includes the uncertainty (full covariance plus the leave-one-view-out jackknife,
  i.e. 50 extra OpenCV solves);
- ``solve_no_jackknife_s``: the same with ``IntrinsicsSettings(jackknife=False)``;
- ``baseline_solve_s``: plain ``cv2.calibrateCamera`` on the same corners with the
  same flags as our default (``CALIB_FIX_K3``) and OpenCV's default termination
  criteria (ours iterates to 100 iterations / 1e-12);
- ``detect_fps``: ``detect_board(image, board)`` at full accuracy (used for
  captures), ``detect_live_fps`` with ``live=True`` (preview frames), and
  ``baseline_detect_fps``: plain ``cv2.findChessboardCorners`` followed by
  ``cv2.cornerSubPix`` with an 11x11 window, as in the OpenCV tutorial;
- ``peak_rss_mb``: peak resident memory of the process at the end (ru_maxrss).

Images: 50 frames of the simulated ``cam_front`` (1280x720, seed 0, deterministic).
Times are the median of ``REPEATS`` runs (time.perf_counter). Full-accuracy
detection is slow, so all three detectors are timed on the same every-5th subset
of the images. Ratios are ours / baseline: ``solve_*_ratio`` > 1 means ours is
slower, ``detect_*_ratio`` < 1 means ours detects fewer frames per second.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/intrinsics.py
"""

import json
import os
import time

import cv2
import numpy as np
from bench_util import REPEATS, log, median_time, peak_rss_mb

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.devices.base import create_device
from backend.sim.demo_rig import DEMO_BOARD

N_VIEWS = 50
IMAGE_SIZE = (1280, 720)
DETECT_EVERY = 5
"""Detection throughput is timed on every 5th image (10 of the 50)."""
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def main():
    started = time.perf_counter()
    board = BoardSpec.parse(DEMO_BOARD)
    log(f"load average at start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores "
        "(other processes skew the timings, the solve's numpy/BLAS part most)")

    # 1. Render the views and detect the board in each (full accuracy, as for captures).
    log(f"rendering {N_VIEWS} views of simulated cam_front ...")
    camera = create_device({"driver": "simulated", "camera": "cam_front", "seed": 0})
    camera.open()
    images = [camera.read().image for _ in range(N_VIEWS)]
    camera.close()
    assert all((image.shape[1], image.shape[0]) == IMAGE_SIZE for image in images), "unexpected image size"

    log(f"detecting the board in {N_VIEWS} views (full accuracy) ...")
    views = []
    for i, image in enumerate(images):
        detection = detect_board(image, board)
        if detection is None:
            raise SystemExit(f"board not found in view {i}; the benchmark needs all {N_VIEWS}")
        views.append(View(f"view_{i:02d}", detection))

    # 2a. Solve: ours with and without the jackknife, and plain OpenCV.
    log(f"timing calibrate_intrinsics (default, with jackknife) x{REPEATS} ...")
    solve_s = median_time(lambda: calibrate_intrinsics(views, board, IMAGE_SIZE))
    log(f"timing calibrate_intrinsics (jackknife=False) x{REPEATS} ...")
    no_jackknife = IntrinsicsSettings(jackknife=False)
    solve_no_jackknife_s = median_time(lambda: calibrate_intrinsics(views, board, IMAGE_SIZE, no_jackknife))

    object_points = [v.detection.object_points(board).astype(np.float32).reshape(-1, 1, 3) for v in views]
    image_points = [v.detection.corners_px.astype(np.float32).reshape(-1, 1, 2) for v in views]

    def baseline_solve():
        return cv2.calibrateCamera(object_points, image_points, IMAGE_SIZE, None, None, flags=cv2.CALIB_FIX_K3)

    log(f"timing cv2.calibrateCamera x{REPEATS} ...")
    baseline_solve_s = median_time(baseline_solve)

    # Sanity check: both solvers should agree on the camera.
    ours = calibrate_intrinsics(views, board, IMAGE_SIZE, no_jackknife)
    rms, K, dist, _, _ = baseline_solve()
    log(f"  ours:     fx {ours.camera.K[0, 0]:.3f} fy {ours.camera.K[1, 1]:.3f} "
        f"cx {ours.camera.K[0, 2]:.3f} cy {ours.camera.K[1, 2]:.3f} rms {ours.rms_px:.4f} px")
    log(f"  baseline: fx {K[0, 0]:.3f} fy {K[1, 1]:.3f} cx {K[0, 2]:.3f} cy {K[1, 2]:.3f} rms {rms:.4f} px")

    # 2b. Detection throughput on the same subset of images.
    subset = images[::DETECT_EVERY]

    def detect_all(live):
        for image in subset:
            detect_board(image, board, live=live)

    def baseline_detect_all():
        for image in subset:
            found, corners = cv2.findChessboardCorners(image, board.corner_grid)
            if found:
                cv2.cornerSubPix(image, corners, (11, 11), (-1, -1), SUBPIX_CRITERIA)

    log(f"timing detect_board (full accuracy) on {len(subset)} images x{REPEATS} ...")
    detect_fps = len(subset) / median_time(lambda: detect_all(live=False))
    log(f"timing detect_board (live=True) on {len(subset)} images x{REPEATS} ...")
    detect_live_fps = len(subset) / median_time(lambda: detect_all(live=True))
    log(f"timing cv2.findChessboardCorners + cornerSubPix on {len(subset)} images x{REPEATS} ...")
    baseline_detect_fps = len(subset) / median_time(baseline_detect_all)

    # 3. Report.
    peak_memory_mb = peak_rss_mb()
    log(f"done in {time.perf_counter() - started:.1f} s; load average at end: {os.getloadavg()[0]:.2f}")
    result = {
        "benchmark": "intrinsics",
        "views": N_VIEWS,
        "image_size": list(IMAGE_SIZE),
        "solve_s": round(solve_s, 4),
        "solve_no_jackknife_s": round(solve_no_jackknife_s, 4),
        "baseline_solve_s": round(baseline_solve_s, 4),
        "solve_ratio": round(solve_s / baseline_solve_s, 2),
        "solve_no_jackknife_ratio": round(solve_no_jackknife_s / baseline_solve_s, 2),
        "detect_fps": round(detect_fps, 2),
        "detect_live_fps": round(detect_live_fps, 2),
        "baseline_detect_fps": round(baseline_detect_fps, 2),
        "detect_ratio": round(detect_fps / baseline_detect_fps, 4),
        "detect_live_ratio": round(detect_live_fps / baseline_detect_fps, 4),
        "peak_rss_mb": round(peak_memory_mb, 1),
        "cpu_count": os.cpu_count(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
