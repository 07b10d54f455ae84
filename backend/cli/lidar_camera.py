"""``calib-studio lidar-camera``: LiDAR-to-camera extrinsics from (image, cloud) files."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import (
    add_init_arguments,
    init_name,
    parse_floats,
    parse_pairs,
    pose_text,
    prints_summary,
    progress_to_stderr,
    read_init,
)
from backend.core.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    lc = sub.add_parser("lidar-camera", help="LiDAR-to-camera extrinsics: T_camera_lidar with its uncertainty")
    lc.add_argument("--camera", type=Path, required=True, metavar="camera.yaml",
                    help="the camera's ROS camera_info YAML or camera JSON (as `intrinsics --out` writes them; the "
                         "JSON carries any model, the photogrammetric one included)")
    lc.add_argument("--pair", action="append", required=True, metavar="IMAGE:CLOUD",
                    help="an image and the cloud taken with it (repeat for every board pose or scene); "
                         "IMAGE:CLOUD1,CLOUD2,... merges several scans of a static scene into one denser cloud")
    lc.add_argument("--method", choices=["target", "vtarget", "edges", "intensity"], default="target",
                    help="target: a board seen by both sensors; vtarget: V-shaped targets of two plates with markers "
                         "(--board takes the V-target's spec); edges: targetless, aligns the edges of the scene; "
                         "intensity: targetless, matches the LiDAR's intensities with the image (needs intensities)")
    lc.add_argument("--cross-check", action="store_true",
                    help="edges, intensity: also solve with the other targetless method and put the two methods' "
                         "agreement into the verdict")
    lc.add_argument("--board", metavar="SPEC",
                    help="board spec, e.g. checkerboard:9x6:0.04 (needed for --method target), or the V-target's, "
                         "e.g. vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50 (for --method vtarget)")
    lc.add_argument("--plate-margin", type=float, metavar="M",
                    help="how far the board's plate reaches beyond the pattern's outer corners (m); default: "
                         "estimated with the transform from the scan lines that cross the plate")
    lc.add_argument("--intrinsics-std", metavar="FX,FY,CX,CY,D1,...",
                    help="target: the 1-sigma of the camera's intrinsics (px: fx, fy, cx, cy, or c, xp, yp for the "
                         "photogrammetric model; then each distortion coefficient), carried into the board poses and "
                         "the result's sigma")
    lc.add_argument("--translation-prior", type=float, metavar="M",
                    help="edges, intensity: hold the initial translation as measured to this 1-sigma (m), for scenes "
                         "whose edges are all far away (they fix the rotation, hardly the translation); without it, "
                         "edges holds the translation at the guess +- 5 cm when the scene cannot determine it")
    add_init_arguments(lc, "initial T_camera_lidar")
    lc.add_argument("--json", action="store_true", help="print the result as one JSON object")
    lc.set_defaults(handler=prints_summary(run_lidar_camera))


def run_lidar_camera(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
    from backend.calib.lidar_camera.service import cli_summary, solve_files
    from backend.core.boards import BoardSpec
    from backend.core.transforms import check_transform
    from backend.core.v_target import VTarget
    from backend.exports.camera_json import load_camera

    pairs = [(image, [Path(c) for c in str(cloud).split(",")]) for image, cloud in parse_pairs(args.pair)]
    camera, _ = load_camera(args.camera)
    if args.method in ("target", "vtarget") and not args.board:
        what, example = (("the V-target's spec", "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50") if args.method == "vtarget"
                         else ("the board's spec", "checkerboard:9x6:0.04"))
        raise InputError(f"--method {args.method} needs {what}, e.g. --board {example}", "--board")
    T_init = read_init(args)
    if T_init is None:
        raise InputError("give the initial T_camera_lidar (the mounting as measured, within ~10 cm and 5 deg) with "
                         "--init or --init-xyzypr", "--init")
    check_transform(T_init, init_name(args))
    board = None if not args.board else VTarget.parse(args.board) if args.method == "vtarget" else BoardSpec.parse(
        args.board)
    lens = None if args.intrinsics_std is None else LensUncertainty.from_sigmas(
        camera, parse_floats(args.intrinsics_std), "--intrinsics-std")
    result = solve_files(camera, board, pairs, T_init, method=args.method, plate_margin_m=args.plate_margin,
                         translation_prior_m=args.translation_prior, cross_check=args.cross_check, lens=lens,
                         progress=progress_to_stderr(False))
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = cli_summary(result)
    if not result.converged:
        print(f"rejected result: {json.dumps(summary)}", file=sys.stderr)
        raise InputError(f"no usable calibration: {(result.warnings or ['the solve failed'])[0]}", "--pair")
    if not args.json:
        import numpy as np

        print(f"T_camera_lidar (x y z m, yaw pitch roll deg): {pose_text(result.T_parent_child)}\n"
              f"{np.array2string(result.T_parent_child, precision=6, suppress_small=True)}\n"
              f"1-sigma trans (m) {summary['std']['trans_m']}  rot (deg, LiDAR axes) {summary['std']['rot_deg']}\n"
              f"residuals {summary['residuals']}")
    return summary
