#!/usr/bin/env python
"""Live board detection benchmark: frames per second at 720p, the live detector against the accurate one.

What it measures, in one run on the same frames:

- ``live_fps``: :class:`backend.calib.board.live_detection.LiveDetector` (the classic search on the full
  frame, else the sector-based one in the frame shrunk to 640x360; refinement at full resolution), as the
  live capture runs it, over every frame in turn (target:
  at least 15); ``live_fps_board`` / ``live_fps_no_board`` over the frames with / without the board;
  ``live_single_fps``: :func:`~backend.calib.board.live_detection.detect_board_live`, which tries every
  contrast treatment on each frame without a board;
- ``accurate_fps``: :func:`backend.calib.board.detection.detect_board` at full accuracy (what a kept
  capture is re-detected with), and ``previous_live_fps``: its ``live=True`` mode, which the live capture
  used before;
- ``baseline_fps``: the in-run baseline, plain ``cv2.findChessboardCorners`` with its default flags plus
  ``CALIB_CB_FAST_CHECK`` on the full frame (no refinement, no second search: the live detector's first
  step alone); ``ratio`` = live_fps / baseline_fps;
- ``found``: frames with a board each method found, of ``board_frames`` (and none may be found in the
  ``no_board_frames``);
- ``max_corner_diff_px``: the largest distance between a live corner and the accurate detector's refined
  corner (its first window) of the same id, over the frames both found;
- ``load_average``: the 1-minute load average at the start and the end.

Frames: ``cam_front`` and ``cam_wide`` of the demo rig (1280x720, mild and strong distortion) rendering the
demo board (``checkerboard:9x6:0.04``) at ``BOARD_FRAMES`` poses each from ``board_poses`` (fill 0.15-0.7 of
the width, up to 40 deg of tilt), and ``NO_BOARD_FRAMES`` each of the background alone. Times are medians over
``REPEATS`` passes of each frame's wall time (time.perf_counter), after a warm-up pass; fps = 1 / the mean of
the per-frame medians. The machine's load skews the absolute figures; the ratio much less.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/live_detection.py
"""

import json
import os
import statistics
import time

import cv2
import numpy as np
from bench_util import log

from backend.calib.board.detection import SUBPIX_WINDOW_FRACTIONS, detect_board, refinement_name
from backend.calib.board.live_detection import FULL_RESOLUTION_FLAGS, LiveDetector, detect_board_live
from backend.core.boards import BoardSpec
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig

CAMERAS = ("cam_front", "cam_wide")
BOARD_FRAMES = 9
NO_BOARD_FRAMES = 2
REPEATS = 3
BEHIND_CAMERA = np.diag([1.0, 1.0, -1.0, 1.0])
"""A board pose behind the camera: the renderer draws the background alone."""


def frames(board):
    """(image, has_board) of every camera's frames, uint8 gray 1280x720."""
    rig = demo_rig()
    out = []
    for name in CAMERAS:
        camera = rig.get(name).intrinsics
        rng = np.random.default_rng(1)
        out += [(render_board_image(camera, board, T, rng), True) for T in board_poses(camera, board, BOARD_FRAMES, 4)]
        out += [(render_board_image(camera, board, BEHIND_CAMERA, rng), False) for _ in range(NO_BOARD_FRAMES)]
    return out


def timed(method, images):
    """(per-frame median wall times (s), each frame's result of the last pass)."""
    results = [method(image) for image in images]  # warm-up
    times = [[] for _ in images]
    for _ in range(REPEATS):
        for i, image in enumerate(images):
            start = time.perf_counter()
            results[i] = method(image)
            times[i].append(time.perf_counter() - start)
    return [statistics.median(t) for t in times], results


def fps(times, rows=slice(None)):
    return round(1.0 / float(np.mean(np.asarray(times)[rows])), 2)


def corner_diff_px(live, accurate):
    """Largest distance (px) between the live and the accurate refined corners of the same ids."""
    refined = accurate.refined[refinement_name(SUBPIX_WINDOW_FRACTIONS[0])]
    return float(np.linalg.norm(live.corners_px[accurate.ids] - refined, axis=1).max())


def main():
    started = time.perf_counter()
    load_start = os.getloadavg()[0]
    log(f"load average at start: {load_start:.2f} on {os.cpu_count()} cores (other processes skew timings)")
    board = BoardSpec.parse(DEMO_BOARD)
    log("rendering the frames ...")
    data = frames(board)
    images = [image for image, _ in data]
    has_board = np.array([flag for _, flag in data])
    stream = LiveDetector(board)
    methods = {
        "live": stream.detect,
        "live_single": lambda image: detect_board_live(image, board),
        "accurate": lambda image: detect_board(image, board),
        "previous_live": lambda image: detect_board(image, board, live=True),
        "baseline": lambda image: cv2.findChessboardCorners(image, board.corner_grid, flags=FULL_RESOLUTION_FLAGS)[0]
        or None,
    }
    times, results = {}, {}
    for name, method in methods.items():
        log(f"timing {name} over {len(images)} frames x{REPEATS} ...")
        times[name], results[name] = timed(method, images)
    both = [i for i in range(len(images)) if results["live"][i] is not None and results["accurate"][i] is not None]
    log(f"done in {time.perf_counter() - started:.1f} s; load average at end: {os.getloadavg()[0]:.2f}")
    result = {
        "benchmark": "live_detection",
        "image": [images[0].shape[1], images[0].shape[0]],
        "board_frames": int(has_board.sum()),
        "no_board_frames": int((~has_board).sum()),
        "live_fps": fps(times["live"]),
        "live_fps_board": fps(times["live"], has_board),
        "live_fps_no_board": fps(times["live"], ~has_board),
        "live_single_fps": fps(times["live_single"]),
        "live_single_fps_no_board": fps(times["live_single"], ~has_board),
        "accurate_fps": fps(times["accurate"]),
        "previous_live_fps": fps(times["previous_live"]),
        "baseline_fps": fps(times["baseline"]),
        "ratio": round(fps(times["live"]) / fps(times["baseline"]), 2),
        "speedup_vs_accurate": round(fps(times["live"]) / fps(times["accurate"]), 2),
        "found": {name: {"board_frames": sum(r is not None for r, b in zip(res, has_board, strict=True) if b),
                         "no_board_frames": sum(r is not None for r, b in zip(res, has_board, strict=True) if not b)}
                  for name, res in results.items()},
        "max_corner_diff_px": round(max(corner_diff_px(results["live"][i], results["accurate"][i])
                                        for i in both), 4),
        "load_average": [round(load_start, 2), round(os.getloadavg()[0], 2)],
        "cpu_count": os.cpu_count(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
