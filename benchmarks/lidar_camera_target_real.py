#!/usr/bin/env python
"""Target LiDAR-to-camera benchmark on the real VLP-16 + fisheye set, against its three reference runs.

The set (``../shared/data/vlp16_camera_checkerboard``: 8 poses of a hand-held 7x6 board of 50 mm squares in a
street, a 1920x1020 fisheye camera and a VLP-16; its README gives the CMU toolbox's three runs, about 2.7 cm and
1.2 deg apart) is solved as the CLI solves it (``service.solve_pairs``: PnP on the detected corners, then the
board's planes and scan-line ends), from reference run 1 turned 3 deg in yaw, pitch and roll and moved 5 cm.

Printed: the times (reading the files, finding the boards in the images, the solve, and all three: what
``calib-studio lidar-camera`` takes), the result's distance from each run (translation norm in mm, rotation angle
in deg) with its 1-sigma and verdict, the in-run baseline (the initial guess's distance from run 1:
``error_ratio`` is the distance after over before), the solved plate margin, and per pose its fit, how far the
solve without it moves the result, and an independent check of each transform made in the image, not in the
LiDAR's frame: the share of the pose's board points (found in the cloud about any of the four transforms) that
the transform projects inside the board's outline as the camera saw it (its detected pattern, grown by the
solved margin and 10 px). Points of the hand and arm holding the board fall outside at every transform, so no
share reaches 1; a transform that puts the board's scan lines above the board in the image has a lower share.
``--figures DIR`` also writes the per-pose evidence (``poses.png``) and crops of three poses with the board points
drawn by run 1 (red) and by the result (green).

Prints exactly one JSON object on stdout; progress goes to stderr.
"""

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from bench_util import log, pose_error

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from calib.lidar_camera.test_target_real import BOARD, CAMERA, VLP16, reference_runs, start  # noqa: E402

from backend.calib.board.detection import detect_board  # noqa: E402
from backend.calib.lidar_camera import service  # noqa: E402
from backend.calib.lidar_camera.target import TargetObservation, camera_board_pose, find_board_points  # noqa: E402
from backend.calib.lidar_camera.target_evidence import (  # noqa: E402
    IN_IMAGE_SEARCH_M,
    pose_evidence,
    shares_in_image_outline,
)
from backend.core.boards import BoardSpec  # noqa: E402
from backend.core.projection import project_cloud  # noqa: E402
from backend.plots.lidar_camera import pose_evidence_figure  # noqa: E402
from backend.plots.render import to_rgb  # noqa: E402


def crops(pairs, observations, T_run, T_result, board, settings, path):
    """Three poses cropped about the board, its points drawn by ``T_run`` (red) and ``T_result`` (green)."""
    rows = []
    for k in (0, 3, 5):
        observation, image = observations[k], pairs[k].image
        points = np.vstack([find_board_points(observation.points_lidar, observation.T_camera_board, T, board,
                                              IN_IMAGE_SEARCH_M, settings,
                                              np.random.default_rng(0), observation.name).plane
                            for T in (T_run, T_result)])
        centre = CAMERA.project_normalised((observation.T_camera_board[:2, 3] / observation.T_camera_board[2, 3])[None])
        u, v = centre[0].astype(int)
        row = []
        for T, colour in ((T_run, (0, 0, 255)), (T_result, (0, 200, 0))):
            drawn = image.copy()
            for x, y in project_cloud(points, T, CAMERA).uv.astype(int):
                cv2.circle(drawn, (x, y), 3, colour, -1)
            row.append(cv2.resize(drawn[max(v - 250, 0):v + 250, max(u - 250, 0):u + 250], (400, 400)))
        rows.append(np.hstack(row))
    cv2.imwrite(str(path), np.vstack(rows))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--figures", type=Path, metavar="DIR", help="also write poses.png and crops.png there")
    args = parser.parse_args()
    board, runs = BoardSpec.parse(BOARD), reference_runs()
    started = time.perf_counter()
    pairs = service.read_pair_files([(VLP16 / f"vlp{i}.jpg", VLP16 / f"lidar{i}.ply") for i in range(1, 9)])
    read_s = time.perf_counter() - started
    log(f"read 8 pairs in {read_s:.1f} s; finding the boards")
    started = time.perf_counter()
    pairs = [replace(p, detection=detect_board(p.image, board)) for p in pairs]
    detect_s = time.perf_counter() - started
    T_init = start()
    started = time.perf_counter()
    result = service.solve_pairs(CAMERA, board, pairs, T_init)
    solve_s = time.perf_counter() - started
    log(f"solved in {solve_s:.1f} s: {result.verdict.level}")

    T = result.T_parent_child
    margin_m = result.diagnostics["plate_margin_m"]
    settings = replace(service.target_settings(board), plate_margin_m=margin_m)
    observations = [TargetObservation(camera_board_pose(p.image, CAMERA, board, detection=p.detection), p.points,
                                      name=p.name) for p in pairs]
    transforms = {"result": T} | {f"run {k + 1}": T_run for k, T_run in enumerate(runs)}
    fits = {pose["name"]: pose for pose in result.diagnostics["poses"]}
    poses = []
    for observation in observations:
        log(f"image check of {observation.name}")
        fit = fits.get(observation.name, {})
        poses.append({"name": observation.name, "plane_points": fit.get("plane_points"),
                      "plane_rms_mm": 1000 * fit["plane_rms_m"] if fit else None,
                      "edge_rms_mm": 1000 * fit["edge_rms_m"] if fit else None,
                      "without_mm": 1000 * fit["without_m"] if fit.get("without_m") is not None else None,
                      "without_deg": fit.get("without_deg"), "without_sigmas": fit.get("without_sigmas"),
                      "image_check": dict(zip(transforms, shares_in_image_outline(
                          observation, list(transforms.values()), CAMERA, board, settings), strict=True))})
    before_mm, before_deg = pose_error(T_init, runs[0])
    after = {name: pose_error(T, T_run) for name, T_run in transforms.items() if name != "result"}
    if args.figures:
        args.figures.mkdir(parents=True, exist_ok=True)
        evidence = pose_evidence(board, observations, result.diagnostics, T, service.target_settings(board))
        figure = pose_evidence_figure(evidence, "VLP-16 set: each pose's board at the result")
        cv2.imwrite(str(args.figures / "poses.png"), to_rgb(figure, 1400)[..., ::-1])
        crops(pairs, observations, runs[0], T, board, settings, args.figures / "crops.png")
    print(json.dumps({
        "data": VLP16.name, "seconds": {"read": read_s, "find_boards": detect_s, "solve": solve_s,
                                        "total": read_s + detect_s + solve_s},
        "from_runs": {name: {"mm": mm, "deg": deg} for name, (mm, deg) in after.items()},
        "nearest_run": min(after, key=lambda name: after[name][0]),
        "before": {"mm": before_mm, "deg": before_deg},
        "error_ratio": after["run 1"][0] / before_mm,
        "sigma": {"mm": [1000 * s for s in result.std["trans_m"]], "deg": result.std["rot_deg"]},
        "plate_margin_mm": 1000 * margin_m, "verdict": result.verdict.to_dict(),
        "image_check_mean_inside": {name: float(np.mean([p["image_check"][name] for p in poses]))
                                    for name in transforms},
        "poses": poses}, indent=1))


if __name__ == "__main__":
    main()
