#!/usr/bin/env python
"""Intrinsics accuracy benchmark: our corners and solve against OpenCV's own pipelines, same images, same model.

Sets:

- ``opencv_left`` / ``opencv_right``: OpenCV's real stereo chessboard images (640x480, 9x6, 25 mm), with
  the reference's model (fixed aspect, k1, k2, p1, p2, k3);
- ``rendered_mild`` / ``rendered_wide``: boards rendered (``backend.sim.board_renderer``) through the demo's
  ``cam_front`` (mild barrel, k1, k2, p1, p2) and ``cam_wide`` (116 deg, k1, k2, p1, p2, k3) with known truth.

Pipelines, each followed by ``cv2.calibrateCamera`` with the set's flags:

- ``ours``: ``detect_board`` + ``calibrate_intrinsics`` (it picks SB's corners or one of their refinements);
- ``opencv_sb``: ``findChessboardCornersSB(flags=CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE)``;
- ``opencv_classic_5`` / ``opencv_classic_11``: ``findChessboardCorners`` + ``cornerSubPix`` with a 5x5
  and (OpenCV's tutorial) 11x11 half-window.

Figures per pipeline: ``rms_px`` (reprojection RMS on its own corners), ``views``; on rendered sets also
``corner_error_px`` (RMS distance of its corners from the true projections) and ``projection_error_px``
(RMS over a 16x9 grid of the distance between where the estimated and the true camera put the same far
point). Ratios are ours / the best OpenCV pipeline of that set (< 1: ours is better). Goal: every ratio <= 1.

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/intrinsics_accuracy.py
"""

import json
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from bench_util import log

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.crossval import grid_pixels
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import transform_points
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "opencv_stereo_chessboard"
RENDERED_VIEWS = 20
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
SB_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE


def opencv_corners(gray, grid, pipeline):
    """(N, 2) corners of OpenCV's ``pipeline`` in ``gray``, or None."""
    if pipeline == "opencv_sb":
        found, corners = cv2.findChessboardCornersSB(gray, grid, flags=SB_FLAGS)
    else:
        found, corners = cv2.findChessboardCorners(gray, grid, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                                   | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if found:
            half = int(pipeline.rsplit("_", 1)[1])
            corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), SUBPIX_CRITERIA)
    return corners.reshape(-1, 2).astype(np.float64) if found else None


def corner_errors(corners, ids, truth):
    """(N, 2) ``corners`` (of corner ``ids``) minus the true ones (a detector may number the board from either end)."""
    forward, backward = corners - truth[ids], corners - truth[::-1][ids]
    return forward if np.abs(forward).mean() < np.abs(backward).mean() else backward


def projection_error_px(estimate: CameraIntrinsics, truth: CameraIntrinsics) -> float:
    """RMS (px) over a 16x9 grid of where ``estimate`` puts the far points ``truth`` sees at the grid's pixels."""
    pixels = grid_pixels(truth.width, truth.height, (16, 9))
    return float(np.sqrt(np.mean(np.sum((estimate.project(truth.rays(pixels)) - pixels) ** 2, axis=1))))


def evaluate(images, board, size, settings, flags, truth=None, true_corners=None):
    """Every pipeline's figures on one set of images."""
    figures = {}
    views = [View(f"view{i:02d}", d) for i, d in enumerate(detect_board(g, board) for g in images) if d is not None]
    ours = calibrate_intrinsics(views, board, size, settings)
    used = [int(v.name[4:]) for v in views]
    chosen = [v.detection.refined.get(ours.corners["chosen"], v.detection.corners_px) for v in views]
    figures["ours"] = {"rms_px": ours.rms_px, "views": len(views), "corners": ours.corners["chosen"]}
    found = {"ours": (used, chosen, [v.detection.ids for v in views], ours.camera)}
    for pipeline in ("opencv_sb", "opencv_classic_5", "opencv_classic_11"):
        detected = [(i, opencv_corners(g, board.corner_grid, pipeline)) for i, g in enumerate(images)]
        detected = [(i, c) for i, c in detected if c is not None]
        rms, K, dist, _, _ = cv2.calibrateCamera([board.object_points] * len(detected),
                                                 [c.astype(np.float32) for _, c in detected], size, np.eye(3), None,
                                                 flags=flags)
        figures[pipeline] = {"rms_px": rms, "views": len(detected)}
        all_ids = [np.arange(board.n_corners)] * len(detected)
        found[pipeline] = ([i for i, _ in detected], [c for _, c in detected], all_ids,
                           CameraIntrinsics("pinhole-radtan", size[0], size[1], K, dist.ravel()[:5]))
    if truth is not None:
        for pipeline, (indices, corners, ids, camera) in found.items():
            errors = np.concatenate([corner_errors(c, k, true_corners[i])
                                     for i, c, k in zip(indices, corners, ids, strict=True)])
            figures[pipeline]["corner_error_px"] = float(np.sqrt(np.mean(np.sum(errors**2, axis=1))))
            figures[pipeline]["projection_error_px"] = projection_error_px(camera, truth)
    opencv = [p for p in figures if p != "ours"]
    ratios = {}
    for key in ("rms_px", "corner_error_px", "projection_error_px"):
        if key in figures["ours"]:
            best = min(opencv, key=lambda p, key=key: figures[p][key])
            ratios[f"{key}_vs_best_opencv"] = figures["ours"][key] / figures[best][key]
            ratios[f"{key}_best_opencv"] = best
    return {"pipelines": figures, "ratios": ratios}


def main():
    started = time.perf_counter()
    results = {}
    real_settings = IntrinsicsSettings(estimate_k3=True, fix_aspect=True, jackknife=False, cross_validate=False)
    board = BoardSpec.parse("checkerboard:9x6:0.025")
    for side in ("left", "right"):
        log(f"opencv_stereo_chessboard {side} ...")
        images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted(DATA.glob(f"{side}*.jpg"))]
        results[f"opencv_{side}"] = evaluate(images, board, (640, 480), real_settings,
                                             cv2.CALIB_FIX_ASPECT_RATIO)
    board = BoardSpec.parse(DEMO_BOARD)
    for name, camera, k3 in (("rendered_mild", "cam_front", False), ("rendered_wide", "cam_wide", True)):
        log(f"{name}: rendering {RENDERED_VIEWS} views of {camera} ...")
        truth = demo_rig().get(camera).intrinsics
        rng = np.random.default_rng(0)
        poses = board_poses(truth, board, RENDERED_VIEWS, 0)
        images = [render_board_image(truth, board, T, rng) for T in poses]
        true_corners = [truth.project(transform_points(T, board.object_points)) for T in poses]
        settings = replace(real_settings, estimate_k3=k3, fix_aspect=False)
        results[name] = evaluate(images, board, truth.image_size, settings, 0 if k3 else cv2.CALIB_FIX_K3,
                                 truth, true_corners)
    worst = {key: max(r["ratios"][key] for r in results.values() if key in r["ratios"])
             for key in ("rms_px_vs_best_opencv", "corner_error_px_vs_best_opencv",
                         "projection_error_px_vs_best_opencv")}
    print(json.dumps({"sets": results, "worst_ratios": worst, "seconds": time.perf_counter() - started}, indent=1))


if __name__ == "__main__":
    main()
