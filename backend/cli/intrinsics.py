"""``calib-studio intrinsics``: calibrate a camera from a folder of board images."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import check_outputs, prints_summary, progress_to_stderr, write_outputs
from backend.core.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    intr = sub.add_parser("intrinsics", help="calibrate a camera from a folder of board or test-field images")
    intr.add_argument("images_dir", type=Path)
    intr.add_argument("--board", required=True, metavar="SPEC",
                      help="a board, e.g. checkerboard:9x6:0.025, or a wall test field of surveyed markers, "
                           "testfield:DICT:MARKER:SURVEY, e.g. testfield:DICT_4X4_50:0.15:wall.csv")
    intr.add_argument("--model", default="pinhole-radtan",
                      choices=["pinhole-radtan", "fisheye-equidistant", "photogrammetric", "splined-stereographic",
                               "auto"],
                      help="photogrammetric: the collinearity model with K1-K3, P1, P2 and the affine A1, A2; "
                           "splined-stereographic: mrcal's splined model, for wide and fisheye lenses; "
                           "auto: compare the lens models on held-out views and solve with the recommended one")
    intr.add_argument("--spline-knots", metavar="NXxNY", help="with --model splined-stereographic: the knots across "
                      "and down, e.g. 12x10 (default: chosen from the views)")
    intr.add_argument("--spline-fov", type=float, metavar="DEG", help="with --model splined-stereographic: the field "
                      "of view across (deg) the knots span (default: the image's plus a margin)")
    intr.add_argument("--for", dest="auto_for", default="any", choices=["any", "camera_info", "kalibr"],
                      help="with --model auto: choose only among the models this export carries (kalibr: no k3); "
                           "--out camera.yaml implies camera_info")
    intr.add_argument("--pixel-size-um", type=float, help="the sensor's pixel pitch (um): the photogrammetric "
                      "model's parameters are reported in mm too")
    intr.add_argument("--k3", action="store_true", help="estimate k3 (pinhole-radtan)")
    intr.add_argument("--no-tangential", action="store_true", help="fix p1 = p2 = 0 (pinhole-radtan)")
    intr.add_argument("--fix-aspect", action="store_true", help="keep fx = fy")
    intr.add_argument("--drop-outliers", action="store_true", help="re-solve without outlier views")
    intr.add_argument("--flat-board", action="store_true", help="hold the board flat: do not solve its bow "
                      "(mrcal's calobject_warp) with the lens")
    intr.add_argument("--keep-outlier-corners", action="store_true", help="do not leave out single corners far "
                      "beyond the corner noise")
    intr.add_argument("--out", type=Path, help="write the camera here: ROS camera_info YAML, the camera JSON "
                      "(any model, with its sigmas) for a .json name, or mrcal's .cameramodel (pinhole-radtan and "
                      "the splined model) for a .cameramodel name")
    intr.add_argument("--camera-name", default="camera", help="camera_name in the YAML")
    intr.add_argument("--json", action="store_true", help="print the result as one JSON object")
    intr.set_defaults(handler=prints_summary(run_intrinsics))


def run_intrinsics(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.intrinsics.service import IntrinsicsSettings, solve_files
    from backend.core.targets import parse_target

    check_outputs(args.out)
    if args.auto_for != "any" and args.model != "auto":
        raise InputError(f"--for {args.auto_for} chooses among models: it applies to --model auto, not "
                         f"--model {args.model}", "for")
    if args.pixel_size_um is not None and not 0 < args.pixel_size_um < 1000:
        raise InputError(f"--pixel-size-um is {args.pixel_size_um}; expected the pixel pitch in micrometres "
                         "(0 to 1000, e.g. 4.8)", "pixel-size-um")
    suffix = args.out.suffix.lower() if args.out is not None else None
    writes_camera_info = args.out is not None and suffix not in (".json", ".cameramodel")
    if suffix == ".cameramodel" and args.model in ("fisheye-equidistant", "photogrammetric"):
        raise InputError(f"--out {args.out} is mrcal's .cameramodel, which cannot carry the {args.model} model; write "
                         "the camera JSON instead (--out camera.json)", "out")
    if writes_camera_info and args.model in ("photogrammetric", "splined-stereographic"):
        raise InputError(f"--out {args.out} is ROS camera_info YAML, which cannot carry the {args.model} model; "
                         "write the camera JSON instead (--out camera.json)", "out")
    if (args.spline_knots or args.spline_fov is not None) and args.model != "splined-stereographic":
        raise InputError(f"--spline-knots and --spline-fov shape the splined model; they do not apply to --model "
                         f"{args.model}", "spline-knots" if args.spline_knots else "spline-fov")
    auto_for = "camera_info" if writes_camera_info and args.model == "auto" else args.auto_for
    settings = IntrinsicsSettings(model=args.model, auto_for=auto_for, estimate_k3=args.k3,
                                  estimate_tangential=not args.no_tangential, fix_aspect=args.fix_aspect,
                                  drop_outliers=args.drop_outliers, pixel_size_um=args.pixel_size_um,
                                  board_flex=not args.flat_board, reject_corners=not args.keep_outlier_corners,
                                  spline_knots=_knots(args.spline_knots), spline_fov_x_deg=args.spline_fov)
    result, skipped = solve_files(args.images_dir, parse_target(args.board), settings,
                                       progress_to_stderr(False))
    for item in skipped:
        print(f"warning: {item['message']}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = result.summary()
    summary["views"] += [{"image": s["input"], "rms_px": None, "used": False} for s in skipped]
    if args.out:
        write_outputs(args.command, [(args.out, _camera_file(result, args.camera_name, suffix))], summary)
    if not args.json:
        cam = result.camera
        print(f"rms {result.rms_px:.4f} px over {sum(v.used for v in result.views)} views")
        if result.photogrammetric:
            for name, p in result.photogrammetric["parameters"].items():
                mm = f"  ({p['value_mm']:.6g} +- {p['sigma_mm']:.2g} {p['unit_mm']})" if "value_mm" in p else ""
                print(f"{name} {p['value_px']:.6g} +- {p['sigma_px']:.2g} {p['unit_px']}{mm}")
        elif result.splined:
            spline, opencv = result.splined, result.splined["opencv"]
            print(f"{spline['lensmodel']}: fx {cam.K[0, 0]:.3f} fy {cam.K[1, 1]:.3f} cx {cam.K[0, 2]:.3f} "
                  f"cy {cam.K[1, 2]:.3f} (held), {spline['spline_values']} spline values\n{spline['detail']}\n"
                  f"the OpenCV model fitted to it at the views' corners (for exports that cannot carry the spline) "
                  f"is off by up to {opencv['max_residual_px']:.3g} px there (RMS {opencv['rms_residual_px']:.3g} px) "
                  f"and {opencv['max_residual_over_image_px']:.3g} px over the "
                  f"{opencv['image_share_inverting']:.0%} of the image where it inverts")
        else:
            print(f"fx {cam.K[0, 0]:.3f} +- {result.std['fx']:.3f}  fy {cam.K[1, 1]:.3f} +- {result.std['fy']:.3f}\n"
                  f"cx {cam.K[0, 2]:.3f} +- {result.std['cx']:.3f}  cy {cam.K[1, 2]:.3f} +- {result.std['cy']:.3f}\n"
                  f"dist {[round(d, 6) for d in cam.dist]}")
        print(f"cross-validation: {result.cross_validation['status']} ({result.cross_validation['detail']})")
        if result.model_comparison:
            print(f"model: {result.model_comparison['reason']}")
        print(f"verdict: {result.verdict.level}: " + "; ".join(result.verdict.reasons))
    return summary


def _camera_file(result, camera_name: str, suffix: str) -> str:
    """The text of ``--out`` by its ``suffix``: the camera JSON (with the sigmas, the board's flex and any
    photogrammetric or splined report), mrcal's .cameramodel, or camera_info."""
    from backend.exports.camera_json import dump_camera_json
    from backend.exports.mrcal_cameramodel import dump_mrcal_cameramodel
    from backend.exports.ros_camera_info import dump_camera_info

    if suffix == ".cameramodel":
        return dump_mrcal_cameramodel(result.camera, camera_name)
    if suffix != ".json":
        return dump_camera_info(result.camera, camera_name)
    extra = {"std": result.std, "rms_px": result.rms_px, "board_flex": result.board_flex}
    return dump_camera_json(result.camera, camera_name,
                            extra | ({"photogrammetric": result.photogrammetric} if result.photogrammetric else {})
                            | ({"splined": result.splined} if result.splined else {}))


def _knots(text: str | None) -> tuple[int, int] | None:
    """``--spline-knots NXxNY`` as (nx, ny); a one-line error for anything else."""
    if text is None:
        return None
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise InputError(f"--spline-knots is {text!r}; expected the knots across and down as NXxNY, e.g. 12x10",
                         "spline-knots")
    return int(parts[0]), int(parts[1])
