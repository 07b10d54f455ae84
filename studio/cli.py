"""``calib-studio``: serve the studio, solve from the command line, export.

Solving commands print exactly one JSON object on stdout with ``--json`` (the
contract in ``../shared/conventions.md``); progress and logs go to stderr. On
failure (bad arguments, bad input, a file that cannot be read or written, a bug)
they exit non-zero with a one-line error on stderr and, with ``--json``,
``{"error": {"message", "input"}}`` on stdout. Output files are checked before the
solve starts; if one still cannot be written after it, the result is kept in a
folder of the system's temp dir that the error names.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
import threading
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from backend.core.errors import InputError, clip, shorten
from backend.exports.text_file import check_writable, write_bytes, write_text

EXIT_INPUT_ERROR = 2
EXIT_INTERNAL_ERROR = 1
EXIT_CANCELLED = 130


class _Parser(argparse.ArgumentParser):
    """argparse whose errors (a missing or unknown option) raise :class:`InputError`, so they reach the user as every
    other error does: the usage, then the one-line error and, with ``--json``, the JSON error."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        raise InputError(message, self.prog)


def _progress_to_stderr(quiet: bool) -> Callable[[float, str], None]:
    def report(fraction: float, message: str) -> None:
        if not quiet:
            print(f"[{fraction * 100:5.1f}%] {message}", file=sys.stderr, flush=True)

    return report


def _add_serve_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="API port (default 8000)")
    parser.add_argument("--viewer-port", type=int, default=8080, help="3D studio port (default 8080)")
    parser.add_argument("--token", default=None, help="access token (generated when binding beyond loopback)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="calib-studio", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="open the studio on a demo session of the simulated rig")
    demo.add_argument("--sessions", type=Path, default=Path("sessions"), help="where the demo session is kept")
    demo.add_argument("--fresh", action="store_true", help="rebuild the demo session from scratch")
    demo.add_argument("--rig", choices=["default", "depth-cell"], default="default",
                      help="default: the simulated robot rig; depth-cell: six simulated Kinect v2 nodes over a "
                           "10 x 15 x 5 m cell, each its own node-agent process")
    _add_serve_args(demo)

    serve = sub.add_parser("serve", help="serve the studio on a folder of sessions")
    serve.add_argument("--sessions", type=Path, required=True, help="folder of sessions")
    _add_serve_args(serve)

    intr = sub.add_parser("intrinsics", help="calibrate a camera from a folder of board images")
    intr.add_argument("images_dir", type=Path)
    intr.add_argument("--board", required=True, help="e.g. checkerboard:9x6:0.025")
    intr.add_argument("--model", default="pinhole-radtan", choices=["pinhole-radtan", "fisheye-equidistant", "auto"],
                      help="auto: compare the lens models on held-out views and solve with the recommended one")
    intr.add_argument("--k3", action="store_true", help="estimate k3 (pinhole-radtan)")
    intr.add_argument("--no-tangential", action="store_true", help="fix p1 = p2 = 0 (pinhole-radtan)")
    intr.add_argument("--fix-aspect", action="store_true", help="keep fx = fy")
    intr.add_argument("--drop-outliers", action="store_true", help="re-solve without outlier views")
    intr.add_argument("--out", type=Path, help="write the ROS camera_info YAML here")
    intr.add_argument("--camera-name", default="camera", help="camera_name in the YAML")
    intr.add_argument("--json", action="store_true", help="print the result as one JSON object")

    ll = sub.add_parser("lidar-lidar", help="register two LiDARs' clouds: T_target_source with its uncertainty")
    ll.add_argument("source_cloud", type=Path, nargs="?",
                    help="cloud of the source (child) LiDAR: .pcd .ply .las .laz .npy (or give --pair)")
    ll.add_argument("target_cloud", type=Path, nargs="?", help="cloud of the target (parent) LiDAR")
    ll.add_argument("--pair", action="append", metavar="SRC:TGT",
                    help="a source cloud and the target cloud taken with it; repeat for every scene (the rig in "
                         "another place): one transform is solved for all, and the scenes cross-check each other")
    init = ll.add_mutually_exclusive_group()
    init.add_argument("--init", type=Path, metavar="T.txt",
                      help="initial T_target_source: a 4x4 in a text file, four whitespace-separated rows")
    init.add_argument("--init-xyzypr", metavar="x,y,z,yaw,pitch,roll",
                      help="initial T_target_source: metres and degrees (ROS order); default: global registration")
    ll.add_argument("--voxel", type=float, metavar="M", help="fine downsampling resolution (m, default 0.1)")
    ll.add_argument("--max-distance", type=float, metavar="M",
                    help="fine correspondence and inlier distance (m, default 0.2)")
    ll.add_argument("--json", action="store_true", help="print the result as one JSON object")

    lc = sub.add_parser("lidar-camera", help="LiDAR-to-camera extrinsics: T_camera_lidar with its uncertainty")
    lc.add_argument("--camera", type=Path, required=True, metavar="camera.yaml",
                    help="the camera's ROS camera_info YAML (as `intrinsics --out` writes it)")
    lc.add_argument("--pair", action="append", required=True, metavar="IMAGE:CLOUD",
                    help="an image and the cloud taken with it (repeat for every board pose or scene); "
                         "IMAGE:CLOUD1,CLOUD2,... merges several scans of a static scene into one denser cloud")
    lc.add_argument("--method", choices=["target", "edges", "intensity"], default="target",
                    help="target: a board seen by both sensors; edges: targetless, aligns the edges of the scene; "
                         "intensity: targetless, matches the LiDAR's intensities with the image (needs intensities)")
    lc.add_argument("--cross-check", action="store_true",
                    help="edges, intensity: also solve with the other targetless method and put the two methods' "
                         "agreement into the verdict")
    lc.add_argument("--board", help="board spec, e.g. checkerboard:9x6:0.04 (needed for --method target)")
    lc.add_argument("--plate-margin", type=float, metavar="M",
                    help="how far the board's plate reaches beyond the pattern's outer corners (m, default one square)")
    lc.add_argument("--translation-prior", type=float, metavar="M",
                    help="edges, intensity: hold the initial translation as measured to this 1-sigma (m), for scenes "
                         "whose edges are all far away (they fix the rotation, hardly the translation)")
    init = lc.add_mutually_exclusive_group()
    init.add_argument("--init", type=Path, metavar="T.txt", help="initial T_camera_lidar: a 4x4 in a text file")
    init.add_argument("--init-xyzypr", metavar="x,y,z,yaw,pitch,roll",
                      help="initial T_camera_lidar: metres and degrees (ROS order)")
    lc.add_argument("--json", action="store_true", help="print the result as one JSON object")

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

    target = sub.add_parser("target", help="a printable calibration board as a PDF at exact scale")
    target.add_argument("spec", metavar="SPEC",
                        help="board spec, e.g. checkerboard:9x6:0.025 or charuco:11x8:0.03:0.022:DICT_5X5_100")
    target.add_argument("--out", type=Path, required=True, metavar="board.pdf", help="the PDF to write")
    target.add_argument("--paper", default="auto",
                        help="a4, letter, a3, a2, a1, a0, or auto (default): the first of these the board fits, "
                             "portrait or landscape")
    target.add_argument("--margin-mm", type=float, default=10.0, metavar="MM",
                        help="white margin around the sheet's edge (mm, default 10, at least 5)")

    from backend.exports.formats import CONVENTION_FORMATS, CONVENTIONS, EXPORT_FORMATS

    rig = sub.add_parser("rig", help="the session's rig as one fused tree: every accepted edge's residual, the loops")
    rig.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
    rig.add_argument("--json", action="store_true", help="print the tree as one JSON object")

    export = sub.add_parser("export", help="export the session's rig or an accepted calibration")
    export.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
    export.add_argument("--format", required=True, choices=list(EXPORT_FORMATS),
                        help="; ".join(f"{name}: {what}" for name, what in EXPORT_FORMATS.items()))
    export.add_argument("--convention", choices=list(CONVENTIONS),
                        help=f"{', '.join(CONVENTION_FORMATS)} only (default optical); "
                             + "; ".join(f"{name}: {what}" for name, what in CONVENTIONS.items()))
    export.add_argument("--cameras", metavar="A,B", type=_names,
                        help="kalibr only: the cameras to write, in order (default: every camera with intrinsics "
                             "Kalibr can describe)")
    export.add_argument("--sensor", help="camera name (camera_info, opencv)")
    export.add_argument("--out", type=Path, help="file to write (default: stdout)")

    report = sub.add_parser("report", help="the session's calibration report: one self-contained HTML file")
    report.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
    report.add_argument("--out", type=Path, required=True, metavar="report.html", help="the HTML file to write")

    network = sub.add_parser("depth-network", help="a depth-camera network: every node's pose in the world with "
                                                   "its uncertainty, and the laser-distance verification")
    network.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/depth-cell")
    network.add_argument("--solve", action="store_true",
                         help="solve every node from its captures first (and accept the results into the rig)")
    network.add_argument("--json", action="store_true", help="print the network as one JSON object")

    node = sub.add_parser("node", help="run a node agent on a sensor's computer: publish its frames over Zenoh "
                                       "and answer the studio's capture requests")
    node.add_argument("--name", required=True, help="the node's name in the rig, e.g. sn1")
    node.add_argument("--device", required=True,
                      help="what to capture from: sim-cell:NODE, kinect2[:SERIAL], realsense[:SERIAL], "
                           "depth-files:DIR, or a driver's JSON settings")
    node.add_argument("--connect", action="append", default=[], metavar="tcp/HOST:7447",
                      help="a Zenoh endpoint to connect to (the studio's or a router's); repeatable")
    node.add_argument("--listen", action="append", default=[], metavar="tcp/0.0.0.0:7448",
                      help="a Zenoh endpoint to listen on; repeatable")
    node.add_argument("--rate", type=float, default=None, metavar="HZ",
                      help="frames published per second (default: the device's own rate)")
    node.add_argument("--voxel", type=float, default=0.02, metavar="M",
                      help="voxel size (m) of the published, compressed clouds (default 0.02; captures are full)")
    return parser


def _check_outputs(*paths: Path | None) -> None:
    """Refuse, before any work, an output file that cannot be written (see :func:`check_writable`)."""
    for path in paths:
        if path is not None:
            check_writable(path)


def _write_outputs(command: str, outputs: list[tuple[Path, str]], summary: dict[str, Any]) -> None:
    """Write each ``(path, text)`` of a solved ``command``. If one fails, the result is not lost: ``summary`` (what
    ``--json`` prints) and the files not yet written are kept by :func:`_keep_result`, and the error names both."""
    for k, (path, text) in enumerate(outputs):
        try:
            write_text(path, text)
        except InputError as exc:
            raise InputError(f"{exc.message}; {_keep_result(command, summary, outputs[k:])}", exc.input) from None
        print(f"wrote {path}", file=sys.stderr)


def _keep_result(command: str, summary: dict[str, Any], unwritten: list[tuple[Path, str]]) -> str:
    """Keep a solved result whose output could not be written, in a new folder of the system's temp dir (``TMPDIR``):
    ``result.json`` and each unwritten file under its own name. Says where, for the error message; if even that
    fails, the result goes to stderr as one ``result: {...}`` line."""
    try:
        folder = Path(tempfile.mkdtemp(prefix=f"calib-studio-{command}-"))
        files = {"result.json": json.dumps(summary, indent=1)}
        for path, text in unwritten:
            files.setdefault(path.name, text)
        for name, text in files.items():
            write_text(folder / name, text)
    except (OSError, InputError):
        print(f"result: {json.dumps(summary)}", file=sys.stderr)
        return "the result could not be kept on disk either: it is the 'result:' line above on stderr"
    return f"the result is kept in {folder} ({', '.join(files)})"


def run_intrinsics(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.intrinsics.service import calibrate_folder
    from backend.calib.intrinsics.solver import IntrinsicsSettings
    from backend.core.boards import BoardSpec
    from backend.exports.ros_camera_info import dump_camera_info

    _check_outputs(args.out)
    settings = IntrinsicsSettings(model=args.model, estimate_k3=args.k3, estimate_tangential=not args.no_tangential,
                                  fix_aspect=args.fix_aspect, drop_outliers=args.drop_outliers)
    result, skipped = calibrate_folder(args.images_dir, BoardSpec.parse(args.board), settings,
                                       _progress_to_stderr(False))
    for item in skipped:
        print(f"warning: {item['message']}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = result.summary()
    summary["views"] += [{"image": s["input"], "rms_px": None, "used": False} for s in skipped]
    if args.out:
        _write_outputs(args.command, [(args.out, dump_camera_info(result.camera, args.camera_name))], summary)
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


def _read_init(args: argparse.Namespace):
    """The initial transform (``T_target_source``, ``T_camera_lidar``) from ``--init`` or ``--init-xyzypr``, or None."""
    import numpy as np

    from backend.core.transforms import from_xyz_ypr

    if args.init is not None:
        expected = "a 4x4 transform as four rows of four whitespace-separated numbers"
        try:
            rows = [line.split() for line in args.init.read_text().splitlines() if line.strip()
                    and not line.lstrip().startswith("#")]
            T = np.array([[float(v) for v in row] for row in rows])
        except OSError as exc:
            raise InputError(f"cannot read the file ({exc.strerror}); expected {expected}", str(args.init)) from None
        except ValueError:
            raise InputError(f"not numbers; expected {expected}", str(args.init)) from None
        if T.shape != (4, 4):
            raise InputError(f"found {len(rows)} row(s) of {sorted({len(r) for r in rows})} value(s); "
                             f"expected {expected}", str(args.init))
        return T
    if args.init_xyzypr is not None:
        try:
            values = [float(v) for v in args.init_xyzypr.split(",")]
        except ValueError:
            values = []
        if len(values) != 6 or not np.isfinite(values).all():
            raise InputError(f"expected six comma-separated numbers x,y,z (m),yaw,pitch,roll (deg), "
                             f"got {shorten(args.init_xyzypr)}", "--init-xyzypr")
        return from_xyz_ypr(np.array(values[:3]), np.radians(values[3:]))
    return None


def _lidar_pairs(args: argparse.Namespace) -> list[tuple[Path, Path]]:
    """The (source, target) cloud files: ``--pair SRC:TGT`` arguments, or the two positional clouds."""
    positional = [p for p in (args.source_cloud, args.target_cloud) if p is not None]
    if args.pair and positional:
        raise InputError("give either SOURCE_CLOUD TARGET_CLOUD or --pair SRC:TGT (repeated), not both", "--pair")
    if args.pair:
        return _pairs(args.pair, "SRC:TGT")
    if len(positional) != 2:
        raise InputError("expected two clouds, SOURCE_CLOUD TARGET_CLOUD, or --pair SRC:TGT for every scene",
                         "SOURCE_CLOUD")
    return [(args.source_cloud, args.target_cloud)]


def run_lidar_lidar(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_lidar.gicp import LidarLidarSettings
    from backend.calib.lidar_lidar.scenes import register_pairs
    from backend.core.transforms import check_transform
    from backend.devices.cloud_files import read_cloud

    progress = _progress_to_stderr(False)
    files = _lidar_pairs(args)
    T_init = _read_init(args)
    if T_init is not None:
        check_transform(T_init, str(args.init) if args.init is not None else "--init-xyzypr")
    settings = LidarLidarSettings()
    if args.voxel is not None:
        if not args.voxel > 0:
            raise InputError(f"expected a positive voxel size in metres, got {args.voxel}", "--voxel")
        settings.voxel_m = args.voxel
    if args.max_distance is not None:
        if not args.max_distance > 0:
            raise InputError(f"expected a positive distance in metres, got {args.max_distance}", "--max-distance")
        settings.max_correspondence_m = args.max_distance
    clouds = {}
    for path in dict.fromkeys(p for pair in files for p in pair):
        progress(0.0, f"reading {path}")
        cloud = read_cloud(path)
        if cloud.dropped_non_finite:
            print(f"warning: {path}: dropped {cloud.dropped_non_finite} non-finite points", file=sys.stderr)
        clouds[path] = cloud.points
    result = register_pairs([(clouds[s], clouds[t]) for s, t in files], T_init, settings, progress,
                            names=[(str(s), str(t)) for s, t in files])
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


def _pairs(values: list[str], form: str = "IMAGE:CLOUD") -> list[tuple[Path, Path]]:
    """``A:B`` arguments (``form`` names them) as path pairs (split at the last colon: paths may hold one)."""
    pairs = []
    for value in values:
        first, sep, second = value.rpartition(":")
        if not sep or not first or not second:
            raise InputError(f"expected {form}, got {shorten(value)}", "--pair")
        pairs.append((Path(first), Path(second)))
    return pairs


def run_lidar_camera(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_camera.service import cli_summary, solve_files
    from backend.core.boards import BoardSpec
    from backend.core.transforms import check_transform
    from backend.exports.ros_camera_info import load_camera_info

    pairs = [(image, [Path(c) for c in str(cloud).split(",")]) for image, cloud in _pairs(args.pair)]
    camera, _ = load_camera_info(args.camera)
    if args.method == "target" and not args.board:
        raise InputError("--method target needs the board's spec, e.g. --board checkerboard:9x6:0.04", "--board")
    T_init = _read_init(args)
    if T_init is None:
        raise InputError("give the initial T_camera_lidar (the mounting as measured, within ~10 cm and 5 deg) with "
                         "--init or --init-xyzypr", "--init")
    check_transform(T_init, str(args.init) if args.init is not None else "--init-xyzypr")
    board = BoardSpec.parse(args.board) if args.board else None
    result = solve_files(camera, board, pairs, T_init, method=args.method, plate_margin_m=args.plate_margin,
                         translation_prior_m=args.translation_prior, cross_check=args.cross_check,
                         progress=_progress_to_stderr(False))
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = cli_summary(result)
    if not result.converged:
        print(f"rejected result: {json.dumps(summary)}", file=sys.stderr)
        raise InputError(f"no usable calibration: {(result.warnings or ['the solve failed'])[0]}", "--pair")
    if not args.json:
        import numpy as np

        from backend.core.transforms import to_xyz_ypr

        xyz, ypr = to_xyz_ypr(result.T_parent_child)
        print(f"T_camera_lidar (x y z m, yaw pitch roll deg): {' '.join(f'{v:.4f}' for v in xyz)}  "
              f"{' '.join(f'{v:.3f}' for v in np.degrees(ypr))}\n"
              f"{np.array2string(result.T_parent_child, precision=6, suppress_small=True)}\n"
              f"1-sigma trans (m) {summary['std']['trans_m']}  rot (deg, LiDAR axes) {summary['std']['rot_deg']}\n"
              f"residuals {summary['residuals']}")
    return summary


def run_multicam(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.multicam.service import parse_named, result_rig, solve_folders
    from backend.core.boards import BoardSpec
    from backend.exports.kalibr_camchain import dump_kalibr_camchain
    from backend.exports.rig_transforms import dump_rig_transforms

    _check_outputs(args.kalibr, args.transforms)
    folders = parse_named(args.camera, "IMAGES_DIR")
    result, warnings = solve_folders(folders, BoardSpec.parse(args.board), parse_named(args.intrinsics, "camera.yaml"),
                                     refine_intrinsics=args.refine_intrinsics, progress=_progress_to_stderr(False))
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
    _write_outputs(args.command, outputs, summary)
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


def _names(value: str) -> list[str]:
    """``a,b`` as ``["a", "b"]`` (empty parts dropped)."""
    return [name for name in value.split(",") if name]


def run_target(args: argparse.Namespace) -> None:
    from backend.exports.target_pdf import board_sheet

    _check_outputs(args.out)
    sheet = board_sheet(args.spec, args.paper, args.margin_mm)
    write_bytes(args.out, sheet.pdf)
    layout = sheet.layout
    orientation = "landscape" if layout.width_mm > layout.height_mm else "portrait"
    print(f"wrote {args.out}: {layout.paper} {orientation}; print it at 100 % / actual size and check the 100 mm bar",
          file=sys.stderr)


def run_rig(args: argparse.Namespace) -> dict[str, Any]:
    """The fused tree of a session (nothing is written); problems (flagged edges, unconnected frames) on stderr."""
    from backend.calib.rig.service import solve_rig
    from backend.store.session import Session

    tree = solve_rig(Session.load(args.session_dir))
    for problem in tree.problems():
        print(f"warning: {problem}", file=sys.stderr)
    summary = tree.summary()
    if not args.json:
        for name, frame in summary["frames"].items():
            xyz = ", ".join(f"{row[3]:.4f}" for row in frame["T_parent_child"][:3])
            sigma = ", ".join("n/a" if v is None else f"{1000 * v:.2f}" for v in frame["std"]["trans_m"])
            print(f"{frame['parent']} -> {name}: {xyz} m (1 sigma {sigma} mm)")
        for edge in summary["edges"]:
            residual = edge["residual"]
            print(f"edge {edge['result_id'] or 'prior'} {edge['parent']} -> {edge['child']}: "
                  f"{1000 * residual['trans_m']:.2f} mm, {residual['rot_deg']:.3f} deg, chi2 {residual['chi2']:.2f}"
                  + (" FLAGGED" if edge["flagged"] else ""))
        for loop in summary["loops"]:
            print(f"loop {' -> '.join(loop['frames'])}: closes to {1000 * loop['trans_m']:.2f} mm, "
                  f"{loop['rot_deg']:.3f} deg")
    return summary


def run_report(args: argparse.Namespace) -> None:
    """Write the session's calibration report (HTML, plots and CSS inline) to ``--out``."""
    from backend.services.report import render_report
    from backend.store.session import Session

    _check_outputs(args.out)
    write_text(args.out, render_report(Session.load(args.session_dir)))
    print(f"wrote {args.out}", file=sys.stderr)


def run_depth_network(args: argparse.Namespace) -> dict[str, Any]:
    """Every node's ``T_world_node`` with its sigma and verdict, and the verification table (solving first with
    ``--solve``); the pose table on stdout without ``--json``."""
    from backend.calib.depth.service import network_summary, pose_table_text
    from backend.store.session import Session

    session = Session.load(args.session_dir)
    summary = network_summary(session, solve=args.solve, progress=_progress_to_stderr(False))
    if not args.json:
        print(pose_table_text(summary))
    return summary


def run_node(args: argparse.Namespace) -> int:
    """Serve one sensor over Zenoh until interrupted (or, started by a studio, until that studio ends)."""
    from backend.devices.node_agent import PARENT_PID_ENV, run_agent, stop_with_parent

    stop = threading.Event()
    if os.environ.get(PARENT_PID_ENV, "").isdigit():
        stop_with_parent(int(os.environ[PARENT_PID_ENV]), stop)
    return run_agent(name=args.name, device=args.device, connect=args.connect, listen=args.listen,
                     rate_hz=args.rate, voxel_m=args.voxel, stop=stop)


def run_export(args: argparse.Namespace) -> None:
    from backend.services.exports import export_text
    from backend.store.session import Session

    _check_outputs(args.out)
    session = Session.load(args.session_dir)
    _, text = export_text(session, args.format, args.sensor, convention=args.convention, cameras=args.cameras)
    if args.out:
        write_text(args.out, text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)


NEGATIVE_VALUE = re.compile(r"^-\.?\d")
"""A value that starts like a negative number (``-0.07,0.63,...``, ``-5``)."""


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string, in the parser and its subcommands, that takes a value."""
    options = set()
    for action in parser._actions:  # argparse has no public listing of its actions
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                options |= _value_options(sub)
        elif action.option_strings and action.nargs != 0:
            options.update(action.option_strings)
    return options


def join_negative_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--opt -0.07,...`` as ``--opt=-0.07,...`` for every option that takes a value: argparse reads a value
    after a space that starts with ``-`` (and is not one plain number) as an unknown option."""
    options = _value_options(parser)
    joined: list[str] = []
    for arg in argv:
        if joined and joined[-1] in options and NEGATIVE_VALUE.match(arg):
            joined[-1] = f"{joined[-1]}={arg}"
        else:
            joined.append(arg)
    return joined


def main(argv: list[str] | None = None) -> int:
    """Run one command; every failure ends here as the one-line error (and the JSON error with ``--json``)."""
    argv = sys.argv[1:] if argv is None else argv
    want_json = "--json" in argv  # until the arguments are parsed
    try:
        parser = build_parser()
        args = parser.parse_args(join_negative_values(parser, argv))
        want_json = getattr(args, "json", False)
        if args.command in ("demo", "serve"):
            from studio.server import serve

            return serve(args)
        run = {"intrinsics": run_intrinsics, "lidar-lidar": run_lidar_lidar, "lidar-camera": run_lidar_camera,
               "multicam": run_multicam, "rig": run_rig, "depth-network": run_depth_network}
        if args.command in run:
            summary = run[args.command](args)
            if want_json:
                print(json.dumps(summary))
        elif args.command == "export":
            run_export(args)
        elif args.command == "report":
            run_report(args)
        elif args.command == "target":
            run_target(args)
        elif args.command == "node":
            return run_node(args)
        return 0
    except InputError as exc:
        return _fail(exc, want_json, EXIT_INPUT_ERROR)
    except OSError as exc:  # a file or device the commands' own checks did not cover
        name = None if exc.filename is None else str(exc.filename)
        return _fail(InputError(exc.strerror or str(exc) or type(exc).__name__, name), want_json, EXIT_INPUT_ERROR)
    except KeyboardInterrupt:
        return _fail(InputError("cancelled"), want_json, EXIT_CANCELLED)
    except Exception as exc:  # a bug: its traceback for the report, then the error line as for any other failure
        traceback.print_exc()
        message = f"internal error ({type(exc).__name__}: {clip(str(exc))}); please report it with the traceback above"
        return _fail(InputError(message), want_json, EXIT_INTERNAL_ERROR)


def _fail(error: InputError, want_json: bool, code: int) -> int:
    """Print ``error`` as the contract says (the line on stderr, the JSON on stdout) and return the exit code."""
    print(error.one_line(), file=sys.stderr, flush=True)
    if want_json:
        try:
            print(json.dumps({"error": error.to_dict()}), flush=True)
        except OSError:  # stdout itself is gone (a closed pipe): the line on stderr has said it
            pass
    return code


if __name__ == "__main__":
    sys.exit(main())
