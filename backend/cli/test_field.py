"""``calib-studio exterior``: a camera's exterior orientation in a wall test field's frame, one pose per image."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from backend.cli._common import parse_floats, pose_text, prints_summary


def add_parser(sub: argparse._SubParsersAction) -> None:
    exterior = sub.add_parser("exterior", help="a camera's pose in a wall test field's frame (spatial resection)")
    exterior.add_argument("images", type=Path, nargs="+", metavar="IMAGE", help="images of the test field")
    exterior.add_argument("--camera", type=Path, required=True, metavar="camera.json",
                          help="the camera's intrinsics: camera JSON (any model) or ROS camera_info YAML")
    exterior.add_argument("--field", required=True, metavar="SPEC",
                          help="the test field, testfield:DICT:MARKER:SURVEY, e.g. testfield:DICT_4X4_50:0.15:wall.csv")
    exterior.add_argument("--intrinsics-std", metavar="FX,FY,CX,CY,D1,...",
                          help="the 1-sigma of the camera's intrinsics (px: fx, fy, cx, cy, or c, xp, yp for the "
                               "photogrammetric model; then each distortion coefficient), carried into each pose's "
                               "sigma; without it the intrinsics are taken as exact")
    exterior.add_argument("--json", action="store_true", help="print the result as one JSON object")
    exterior.set_defaults(handler=prints_summary(run_exterior))


def run_exterior(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
    from backend.calib.test_field.service import pose_entry, resect_image
    from backend.core.test_field import TestField
    from backend.devices.image_io import read_image
    from backend.exports.camera_json import load_camera

    started = time.perf_counter()
    camera, _ = load_camera(args.camera)
    test_field = TestField.parse(args.field)
    lens = None if args.intrinsics_std is None else LensUncertainty.from_sigmas(
        camera, parse_floats(args.intrinsics_std), "--intrinsics-std")
    poses = {}
    for path in args.images:
        result = resect_image(read_image(path, grayscale=True), camera, test_field, path.name, lens)
        for warning in result.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        poses[path.name] = pose_entry(result)
        if not args.json:
            print(f"{path.name}: T_wall_camera (x y z m, yaw pitch roll deg) {pose_text(result.T_parent_child)}; "
                  f"1-sigma trans (m) {result.std['trans_m']} "
                  f"rot (deg) {result.std['rot_deg']}; rms {result.residuals['rms_px']:.3f} px over "
                  f"{result.residuals['markers_used']} markers; verdict {result.verdict.level}: "
                  + "; ".join(result.verdict.reasons))
    return {"poses": poses, "seconds": time.perf_counter() - started}
