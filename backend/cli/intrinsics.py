"""``calib-studio intrinsics``: calibrate a camera from a folder of board images."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import check_outputs, prints_summary, progress_to_stderr, write_outputs
from backend.core.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    intr = sub.add_parser("intrinsics", help="calibrate a camera from a folder of board images")
    intr.add_argument("images_dir", type=Path)
    intr.add_argument("--board", required=True, help="e.g. checkerboard:9x6:0.025")
    intr.add_argument("--model", default="pinhole-radtan", choices=["pinhole-radtan", "fisheye-equidistant", "auto"],
                      help="auto: compare the lens models on held-out views and solve with the recommended one")
    intr.add_argument("--for", dest="auto_for", default="any", choices=["any", "camera_info", "kalibr"],
                      help="with --model auto: choose only among the models this export carries (kalibr: no k3)")
    intr.add_argument("--k3", action="store_true", help="estimate k3 (pinhole-radtan)")
    intr.add_argument("--no-tangential", action="store_true", help="fix p1 = p2 = 0 (pinhole-radtan)")
    intr.add_argument("--fix-aspect", action="store_true", help="keep fx = fy")
    intr.add_argument("--drop-outliers", action="store_true", help="re-solve without outlier views")
    intr.add_argument("--out", type=Path, help="write the ROS camera_info YAML here")
    intr.add_argument("--camera-name", default="camera", help="camera_name in the YAML")
    intr.add_argument("--json", action="store_true", help="print the result as one JSON object")
    intr.set_defaults(handler=prints_summary(run_intrinsics))


def run_intrinsics(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.intrinsics.service import IntrinsicsSettings, solve_files
    from backend.core.boards import BoardSpec
    from backend.exports.ros_camera_info import dump_camera_info

    check_outputs(args.out)
    if args.auto_for != "any" and args.model != "auto":
        raise InputError(f"--for {args.auto_for} chooses among models: it applies to --model auto, not "
                         f"--model {args.model}", "for")
    settings = IntrinsicsSettings(model=args.model, auto_for=args.auto_for, estimate_k3=args.k3,
                                  estimate_tangential=not args.no_tangential, fix_aspect=args.fix_aspect,
                                  drop_outliers=args.drop_outliers)
    result, skipped = solve_files(args.images_dir, BoardSpec.parse(args.board), settings,
                                       progress_to_stderr(False))
    for item in skipped:
        print(f"warning: {item['message']}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = result.summary()
    summary["views"] += [{"image": s["input"], "rms_px": None, "used": False} for s in skipped]
    if args.out:
        write_outputs(args.command, [(args.out, dump_camera_info(result.camera, args.camera_name))], summary)
    if not args.json:
        cam = result.camera
        print(f"rms {result.rms_px:.4f} px over {sum(v.used for v in result.views)} views\n"
              f"fx {cam.K[0, 0]:.3f} +- {result.std['fx']:.3f}  fy {cam.K[1, 1]:.3f} +- {result.std['fy']:.3f}\n"
              f"cx {cam.K[0, 2]:.3f} +- {result.std['cx']:.3f}  cy {cam.K[1, 2]:.3f} +- {result.std['cy']:.3f}\n"
              f"dist {[round(d, 6) for d in cam.dist]}\n"
              f"cross-validation: {result.cross_validation['status']} ({result.cross_validation['detail']})")
        if result.model_comparison:
            print(f"model: {result.model_comparison['reason']}")
        print(f"verdict: {result.verdict.level}: " + "; ".join(result.verdict.reasons))
    return summary
