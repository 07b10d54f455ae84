"""``calib-studio lidar-lidar``: register two LiDARs' clouds (one scene or several) through the LiDAR-LiDAR service."""

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
    ll = sub.add_parser("lidar-lidar", help="register two LiDARs' clouds: T_target_source with its uncertainty")
    ll.add_argument("source_cloud", type=Path, nargs="?",
                    help="cloud of the source (child) LiDAR: .pcd .ply .las .laz .npy .lvx (or give --pair)")
    ll.add_argument("target_cloud", type=Path, nargs="?", help="cloud of the target (parent) LiDAR")
    ll.add_argument("--pair", action="append", metavar="SRC:TGT",
                    help="a source cloud and the target cloud taken with it; repeat for every scene (the rig in "
                         "another place): one transform is solved for all, and the scenes cross-check each other")
    add_init_arguments(ll, "initial T_target_source", "; default: global registration")
    ll.add_argument("--voxel", type=float, metavar="M", help="fine downsampling resolution (m, default 0.1)")
    ll.add_argument("--max-distance", type=float, metavar="M",
                    help="fine correspondence and inlier distance (m, default 0.2)")
    ll.add_argument("--json", action="store_true", help="print the result as one JSON object")
    ll.set_defaults(handler=prints_summary(run_lidar_lidar))


def _lidar_pairs(args: argparse.Namespace) -> list[tuple[Path, Path]]:
    """The (source, target) cloud files: ``--pair SRC:TGT`` arguments, or the two positional clouds."""
    positional = [p for p in (args.source_cloud, args.target_cloud) if p is not None]
    if args.pair and positional:
        raise InputError("give either SOURCE_CLOUD TARGET_CLOUD or --pair SRC:TGT (repeated), not both", "--pair")
    if args.pair:
        return parse_pairs(args.pair, "SRC:TGT")
    if len(positional) != 2:
        raise InputError("expected two clouds, SOURCE_CLOUD TARGET_CLOUD, or --pair SRC:TGT for every scene",
                         "SOURCE_CLOUD")
    return [(args.source_cloud, args.target_cloud)]


def run_lidar_lidar(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_lidar.service import solve_files
    from backend.core.transforms import check_transform

    files = _lidar_pairs(args)
    T_init = read_init(args)
    if T_init is not None:
        check_transform(T_init, init_name(args))
    if args.voxel is not None and not args.voxel > 0:
        raise InputError(f"expected a positive voxel size in metres, got {args.voxel}", "--voxel")
    if args.max_distance is not None and not args.max_distance > 0:
        raise InputError(f"expected a positive distance in metres, got {args.max_distance}", "--max-distance")
    result = solve_files(files, T_init, voxel_m=args.voxel, max_correspondence_m=args.max_distance,
                         progress=progress_to_stderr(False), warn=warn)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    residuals, diagnostics = result.residuals, result.diagnostics
    summary = {"T_target_source": result.T_parent_child.tolist(), "fitness": residuals["fitness"],
               "rmse_m": residuals["rmse_m"], "c2c_m": residuals["c2c_m"], "std": result.std,
               "seconds": result.seconds, "verdict": result.verdict.to_dict(), "scenes": diagnostics["scenes"],
               "scene_spread": diagnostics["scene_spread"]}
    if not result.converged:
        # Not an answer to use: say so the contract's way (non-zero exit, {"error": ...}), the numbers to stderr.
        print(f"rejected result: {json.dumps(summary)}", file=sys.stderr)
        problems = [w for w in result.warnings if "not accepted" in w] or ["the refinement failed"]
        raise InputError(f"no usable alignment: {problems[0]}", ",".join(f"{s}:{t}" for s, t in files))
    print(f"verdict: {result.verdict.level}: {'; '.join(result.verdict.reasons)}", file=sys.stderr)
    if not args.json:
        import numpy as np

        from backend.core.transforms import to_xyz_ypr

        xyz, ypr = to_xyz_ypr(result.T_parent_child)
        trans, rot = summary["std"]["trans_m"], summary["std"]["rot_deg"]
        print(f"T_target_source (x y z m, yaw pitch roll deg): {' '.join(f'{v:.4f}' for v in xyz)}  "
              f"{' '.join(f'{v:.3f}' for v in np.degrees(ypr))}\n"
              f"{np.array2string(result.T_parent_child, precision=6, suppress_small=True)}\n"
              f"fitness {residuals['fitness']:.3f}  rmse {residuals['rmse_m']:.4f} m  converged {result.converged}\n"
              f"1-sigma trans (m) {trans}  rot (deg, source axes) {rot}")
        for k, scene in enumerate(summary["scenes"]):
            xyz, ypr = to_xyz_ypr(np.array(scene["T_target_source"]))
            print(f"scene {k + 1} (pairs {scene['pairs']}): {' '.join(f'{v:.4f}' for v in xyz)}  "
                  f"{' '.join(f'{v:.3f}' for v in np.degrees(ypr))}  fitness {scene['fitness']:.3f}  "
                  f"agrees {scene['agrees']}")
        print(f"verdict {result.verdict.level}")
    return summary
