"""``calib-studio time-offset``: the offset between a camera's and a LiDAR's (3D, or a 2D scanner's) clocks, from a
board carried through both views (``t_lidar = t_camera + offset``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import (
    add_camera_corners_arguments,
    add_init_arguments,
    prints_summary,
    progress_to_stderr,
    read_init,
)
from backend.core.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    to = sub.add_parser("time-offset", help="the time offset between a camera and a 3D LiDAR or 2D scanner (t_lidar "
                                            "= t_camera + offset) from a board carried through both views")
    add_camera_corners_arguments(to)
    to.add_argument("--scans", type=Path, required=True,
                    help="a folder of clouds (.pcd .ply .las .laz .npy .lvx) named by their time stamp in ns; "
                         "clouds whose points all have z = 0 are a 2D scanner's: its line through the board is "
                         "lined up with where the board cuts its scan plane (turn the board about a vertical axis "
                         "while carrying it across)")
    to.add_argument("--board", required=True, help="the board, e.g. checkerboard:7x5:0.1")
    add_init_arguments(to, "T_camera_lidar placing the board in the clouds")
    to.add_argument("--max-offset", type=float, default=0.5, metavar="S",
                    help="search the offset within ±S seconds (default 0.5)")
    to.add_argument("--json", action="store_true", help="print the result as one JSON object")
    to.set_defaults(handler=prints_summary(run_time_offset))


def run_time_offset(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.time_offset.service import settings, solve_files

    T_camera_lidar = read_init(args)
    if T_camera_lidar is None:
        raise InputError("the board is found in the clouds where T_camera_lidar puts it: give --init or "
                         "--init-xyzypr", "--init")
    if not 0 < args.max_offset <= 5.0:
        raise InputError(f"expected 0 to 5 seconds, got {args.max_offset}", "--max-offset")
    result = solve_files(args.camera, args.images or args.detections, args.scans, args.board, T_camera_lidar,
                         settings(args.max_offset), progress_to_stderr(False))
    print(f"verdict: {result.verdict.level}: {'; '.join(result.verdict.reasons)}", file=sys.stderr)
    if not args.json:
        print(f"time offset {1e3 * result.offset_s:.3f} ms (t_lidar = t_camera + offset), sigma "
              f"{1e3 * result.std_s:.3f} ms")
    return result.summary()
