#!/usr/bin/env python
"""Photogrammetric model benchmark: our self-calibrating bundle adjustment against OpenCV on the same corners.

Sets:

- ``opencv_left`` / ``opencv_right``: OpenCV's real stereo chessboard images (640x480, 9x6, 25 mm); the reference is
  OpenCV's ``calibrateCamera`` with its five coefficients and a free aspect (the model the photogrammetric one
  contains with ``A1`` standing in for fx != fy), on the corner set our solve chose;
- ``blackfly_sim``: the disaster-response robot's camera (1280x1024, 4 mm, 4.8 um pixels) with a photogrammetric
  truth (affine terms included), 14 views of a 9x6 board straight and turned 90 degrees, corners with 0.08 px noise.

Figures: ``rms_px`` of both; ``rms_ratio`` ours / OpenCV (<= 1: ours fits no worse); ``solve_s`` of the bare bundle
adjustment (no sigmas) and OpenCV's ``calibrateCamera``, and their ratio; the K1-K2, K2-K3 and K1-K3 correlations
beside the disaster-response team's (-0.964, -0.983, +0.907, from 12 test-field images); on the simulated set each
parameter's error over its sigma. mrcal has no model with affine terms, so it is not a reference here (its lens
models are issue 24's).

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/photogrammetric.py
"""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
from bench_util import log, median_time

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.photogrammetric import INTERIOR
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, _calibrate, calibrate_intrinsics
from backend.core.boards import BoardSpec

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.calib.intrinsics.test_photogrammetric import BOARD as SIM_BOARD  # noqa: E402
from tests.calib.intrinsics.test_photogrammetric import TRUTH, noisy_views  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "opencv_stereo_chessboard"
REAL_BOARD = BoardSpec.parse("checkerboard:9x6:0.025")
PAPER = {"K1-K2": -0.964, "K2-K3": -0.983, "K1-K3": 0.907}
SETTINGS = IntrinsicsSettings(model="photogrammetric")


def correlations(result) -> dict:
    names, matrix = result.correlation_names, np.array(result.correlation)
    pick = {pair: (names.index(pair[:2]), names.index(pair[3:])) for pair in PAPER}
    return {pair: round(float(matrix[i, j]), 3) for pair, (i, j) in pick.items()}


def compare(name: str, views: list[View], board: BoardSpec, size: tuple[int, int]) -> dict:
    log(f"{name}: {len(views)} views")
    ours = calibrate_intrinsics(views, board, size, SETTINGS)
    chosen = ours.corners["chosen"]
    image_points = [(v.detection.refined[chosen] if chosen != "sb" else v.detection.corners_px).astype(np.float32)
                    for v in views]
    object_points = [v.detection.object_points(board) for v in views]
    rms, *_ = cv2.calibrateCamera(object_points, image_points, size, np.eye(3), None, flags=0)
    picked = [View(v.name, v.detection) for v in views] if chosen == "sb" else [
        View(v.name, type(v.detection)(p.astype(float), v.detection.ids, v.detection.image_size))
        for v, p in zip(views, image_points, strict=True)]
    ours_s = median_time(lambda: _calibrate(picked, board, size, SETTINGS))
    opencv_s = median_time(lambda: cv2.calibrateCamera(object_points, image_points, size, np.eye(3), None, flags=0))
    return {"views": len(views), "corners": chosen, "rms_px": {"ours": ours.rms_px, "opencv_5": rms},
            "rms_ratio": ours.rms_px / rms, "solve_s": {"ours": ours_s, "opencv_5": opencv_s},
            "solve_ratio": ours_s / opencv_s, "correlations": {"ours": correlations(ours), "paper": PAPER},
            "opencv_conversion_max_px": ours.photogrammetric["opencv"]["max_residual_px"],
            "verdict": ours.verdict.level}, ours


def main() -> None:
    report = {}
    for side in ("left", "right"):
        paths = sorted(DATA.glob(f"{side}*.jpg"))
        views = [View(p.name, detect_board(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), REAL_BOARD)) for p in paths]
        report[f"opencv_{side}"], _ = compare(f"opencv_{side}", [v for v in views if v.detection], REAL_BOARD,
                                              (640, 480))
    report["blackfly_sim"], result = compare("blackfly_sim", noisy_views(14, 0), SIM_BOARD, (1280, 1024))
    truth = np.r_[TRUTH.K[0, 0], TRUTH.K[0, 2], TRUTH.K[1, 2], TRUTH.dist]
    found = result.photogrammetric["parameters"]
    report["blackfly_sim"]["error_over_sigma"] = {
        name: round((found[name]["value_px"] - truth[k]) / found[name]["sigma_px"], 2)
        for k, name in enumerate(INTERIOR)}
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
