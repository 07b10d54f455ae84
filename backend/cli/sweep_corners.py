"""``calib-studio sweep-corners``: LiDAR-to-camera from board corners in a swept scanner's intensity image, and a
camera's pan axis, from (sweep, image) files."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import (
    add_init_arguments,
    init_name,
    parse_pairs,
    prints_summary,
    progress_to_stderr,
    read_init,
    warn,
)
from backend.core.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    sc = sub.add_parser("sweep-corners", help="LiDAR-to-camera from a board's corners in a swept scanner's "
                        "intensity image: T_camera_lidar, or with pan readings the camera's pan axis")
    sc.add_argument("--camera", type=Path, required=True, metavar="camera.yaml",
                    help="the camera's ROS camera_info YAML or camera JSON (as `intrinsics --out` writes them)")
    sc.add_argument("--board", required=True, metavar="SPEC",
                    help="the checkerboard both sensors see, e.g. checkerboard:8x6:0.057")
    sc.add_argument("--sweep", action="append", required=True, metavar="SWEEP:IMAGE",
                    help="a sweep of the board and the camera's image of it (repeat for every placement); the sweep "
                         "as a session keeps a swept capture: SWEEP.npy (x, y, z in the mount frame (m), intensity) "
                         "and SWEEP.json beside it (servo_angles_rad, step_counts, geometry)")
    sc.add_argument("--pan-deg", action="append", type=float, metavar="DEG",
                    help="the pan head's reading (deg) at each --sweep's image, one per --sweep in the same order; "
                         "readings at two or more positions solve the camera's pan axis")
    sc.add_argument("--geometry", type=Path, metavar="geometry.json",
                    help="assemble every sweep with this sweep geometry (axis, T_servo_scanner, zero_offset_rad, "
                         "as a sweep calibration gives it); default the one each sweep was captured with")
    add_init_arguments(sc, "the mounting guess T_camera_lidar at pan reading 0")
    sc.add_argument("--json", action="store_true", help="print the result as one JSON object")
    sc.set_defaults(handler=prints_summary(run_sweep_corners))


def run_sweep_corners(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_camera.service import cli_summary
    from backend.calib.lidar_camera.sweep_corners_service import file_shots, solve_corners, solve_pan
    from backend.core.boards import BoardSpec
    from backend.core.transforms import check_transform
    from backend.exports.camera_json import load_camera

    camera, _ = load_camera(args.camera)
    board = BoardSpec.parse(args.board)
    if board.kind != "checkerboard":
        raise InputError(f"the corners method finds a checkerboard in the sweep, not a {board.kind} board", "--board")
    T_init = read_init(args)
    if T_init is None:
        raise InputError("give the mounting guess T_camera_lidar at pan reading 0 (within ~10 cm and 5 deg) with "
                         "--init or --init-xyzypr: it pairs the corners of a board that looks the same turned a half "
                         "turn", "--init")
    T_init, _ = check_transform(T_init, init_name(args))
    shots, geometry = file_shots(parse_pairs(args.sweep, "SWEEP:IMAGE", "--sweep"), args.pan_deg,
                                 None if args.geometry is None else _read_geometry(args.geometry))
    progress = progress_to_stderr(False)
    if len({shot.pan_deg for shot in shots}) > 1:
        pan, _, skipped = solve_pan(shots, board, camera, geometry, T_init, progress=progress)
        for reason in skipped:
            warn(reason)
        summary = pan.summary()
        if not args.json:
            axis = pan.pan_axis()
            print(f"pan axis (LiDAR frame): {' '.join(f'{v:.5f}' for v in axis['axis'])} through "
                  f"{' '.join(f'{v:.4f}' for v in axis['axis_point_m'])} m, 1-sigma {axis['axis_sigma_deg']:.3f} deg\n"
                  f"verdict {summary['verdict']['level']}")
        return summary
    result, _ = solve_corners(shots, board, camera, geometry, T_init, progress=progress)
    for warning in result.warnings:
        warn(warning)
    summary = cli_summary(result) | {"placements": result.diagnostics["placements"]}
    if not result.converged:
        print(f"rejected result: {json.dumps(summary)}", file=sys.stderr)
        raise InputError(f"no usable calibration: {(result.warnings or ['the solve failed'])[0]}", "--sweep")
    if not args.json:
        print(f"T_camera_lidar:\n{result.T_parent_child.round(6)}\nverdict {summary['verdict']['level']}")
    return summary


def _read_geometry(path: Path):
    """The :class:`~backend.core.sweep_geometry.SweepGeometry` of a JSON file; :class:`InputError` naming it."""
    from backend.core.sweep_geometry import SweepGeometry

    try:
        return SweepGeometry.from_dict(json.loads(path.read_text()))
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror})", str(path)) from None
    except (ValueError, TypeError, AttributeError) as exc:
        raise InputError(f"expected a sweep geometry JSON (axis, T_servo_scanner, zero_offset_rad): {exc}",
                         str(path)) from None
