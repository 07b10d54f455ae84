"""``calib-studio multicam``: a multi-camera rig from one joint solve over folders of board images."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import check_outputs, prints_summary, progress_to_stderr, write_outputs
from backend.core.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    mc = sub.add_parser("multicam", help="multi-camera rig: every T_ref_cam from one joint solve, with uncertainty")
    mc.add_argument("--camera", action="append", required=True, metavar="NAME=IMAGES_DIR",
                    help="a camera and its folder of board images (repeat; the first is the reference); frames are "
                         "matched across cameras by the number in their file names")
    mc.add_argument("--board", required=True, help="e.g. checkerboard:9x6:0.025")
    mc.add_argument("--intrinsics", action="append", default=[], metavar="NAME=camera.yaml",
                    help="a camera's ROS camera_info YAML, held fixed (cameras without one are calibrated from their "
                         "own images and refined with the rig)")
    mc.add_argument("--refine-intrinsics", action="store_true", help="also refine the intrinsics given")
    mc.add_argument("--kalibr", type=Path, metavar="camchain.yaml", help="write the rig as a Kalibr camchain YAML")
    mc.add_argument("--transforms", type=Path, metavar="rig.yaml",
                    help="write every T_ref_cam with its sigma and static_transform_publisher line")
    mc.add_argument("--json", action="store_true", help="print the result as one JSON object")
    mc.set_defaults(handler=prints_summary(run_multicam))


def run_multicam(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.multicam.service import parse_named, result_rig, solve_files
    from backend.core.boards import BoardSpec
    from backend.exports.kalibr_camchain import dump_kalibr_camchain
    from backend.exports.rig_transforms import dump_rig_transforms

    check_outputs(args.kalibr, args.transforms)
    folders = parse_named(args.camera, "IMAGES_DIR")
    result, warnings = solve_files(folders, BoardSpec.parse(args.board), parse_named(args.intrinsics, "camera.yaml"),
                                     refine_intrinsics=args.refine_intrinsics, progress=progress_to_stderr(False))
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = result.summary()
    if not result.converged:
        print(f"rejected result: {json.dumps(summary)}", file=sys.stderr)
        raise InputError(f"no usable calibration: {(result.warnings or ['the solve failed'])[0]}", "--camera")
    outputs = []
    if args.kalibr:
        outputs.append((args.kalibr, dump_kalibr_camchain(list(result.cameras.items()), result.T_ref_cam)))
    if args.transforms:
        outputs.append((args.transforms, dump_rig_transforms(result_rig(result))))
    write_outputs(args.command, outputs, summary)
    if not args.json:
        import numpy as np

        from backend.core.transforms import to_xyz_ypr

        for name, T in result.T_ref_cam.items():
            xyz, ypr = to_xyz_ypr(T)
            std = summary["std"][name]
            print(f"T_{result.reference}_{name} (x y z m, yaw pitch roll deg): {' '.join(f'{v:.5f}' for v in xyz)}  "
                  f"{' '.join(f'{v:.4f}' for v in np.degrees(ypr))}  1-sigma {std['trans_m']} m {std['rot_deg']} deg  "
                  f"rms {result.rms_px[name]:.3f} px")
    return summary
