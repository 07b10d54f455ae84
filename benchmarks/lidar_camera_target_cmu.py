#!/usr/bin/env python
"""Where the VLP-16 set's reference runs come from: the CMU toolbox's own method, redone on the same input.

The set's README gives three runs of the CMU Laser-Camera Calibration Toolbox. That toolbox uses the board's planes
only, and keeps as a board's points every point within 2 cm of its plane and 1 m of the user's click, which takes in
the hand, arm and body holding it (``tests/calib/lidar_camera/cmu_reference.py`` redoes it). This script runs its two
stages on each pose's points kept two ways, over several RANSAC seeds:
- ``toolbox``: as the toolbox keeps them;
- ``board``: only those within 0.22 m of the board's centre in the scan.
The camera's board planes come from PnP on the set's ``camera.yaml``; they agree with the author's own Bouguet poses
(``Calib_Results.mat`` in the toolbox's repository) within 0.5 deg and 6 mm. The click is the scan's point nearest the
board's centre as run 1 places it, a point on the board as a user's click would be.

Printed: this project's target solve (``service.solve_pairs``, from run 1 turned 3 deg and moved 5 cm) from the
three runs; and per selection and seed, its result from the three runs and from this project's solve (translation
norm in mm, rotation angle in deg), the points kept per pose and the share of them farther than 0.3 m from the
board's centre (not the board's). The baseline is the toolbox selection: ``ratio`` is the board selection's median
rotation from this project's solve over the toolbox selection's (below 1: on the board's points the reference
method comes nearer the solve).

Prints exactly one JSON object on stdout; progress goes to stderr.
"""

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from bench_util import log, pose_error

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from calib.lidar_camera.cmu_reference import board_plane, clicks_on_boards, reproduce, scan_points  # noqa: E402
from calib.lidar_camera.test_target_real import BOARD, CAMERA, VLP16, reference_runs, start  # noqa: E402

from backend.calib.board.detection import detect_board  # noqa: E402
from backend.calib.lidar_camera import service  # noqa: E402
from backend.calib.lidar_camera.target import camera_board_pose  # noqa: E402
from backend.core.boards import BoardSpec  # noqa: E402

SEEDS = range(5)


def distance(T, T_other):
    """:func:`bench_util.pose_error` of ``T`` from ``T_other``, as printed: ``{"mm": ..., "deg": ...}``."""
    mm, deg = pose_error(T, T_other)
    return {"mm": round(mm, 1), "deg": round(deg, 2)}


def main():
    board, runs = BoardSpec.parse(BOARD), reference_runs()
    pairs = service.read_pair_files([(VLP16 / f"vlp{i}.jpg", VLP16 / f"lidar{i}.ply") for i in range(1, 9)])
    pairs = [replace(p, detection=detect_board(p.image, board)) for p in pairs]
    log("solving as the CLI does")
    T_ours = service.solve_pairs(CAMERA, board, pairs, start()).T_parent_child
    T_camera_boards = [camera_board_pose(p.image, CAMERA, board, detection=p.detection) for p in pairs]
    clouds = [scan_points(p.points) for p in pairs]
    clicks = clicks_on_boards(clouds, T_camera_boards, board.object_points.mean(axis=0), runs[0])
    rows = []
    for seed in SEEDS:
        log(f"RANSAC seed {seed}")
        for selection, found in reproduce([board_plane(T) for T in T_camera_boards], clouds, clicks, seed).items():
            rows.append({"selection": selection, "seed": seed, "points": found.points,
                         "off_board_share": [round(share, 3) for share in found.off_board_share],
                         "from_runs": [distance(found.T_camera_lidar, T_run) for T_run in runs],
                         "from_ours": distance(found.T_camera_lidar, T_ours)})
    median_deg = {selection: float(np.median([row["from_ours"]["deg"] for row in rows
                                              if row["selection"] == selection])) for selection in ("board", "toolbox")}
    print(json.dumps({"data": VLP16.name, "ours_from_runs": [distance(T_ours, T_run) for T_run in runs],
                      "from_ours_median_deg": median_deg, "ratio": median_deg["board"] / median_deg["toolbox"],
                      "reproductions": rows}, indent=1))


if __name__ == "__main__":
    main()
