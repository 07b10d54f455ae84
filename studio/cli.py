"""``calib-studio``: serve the studio, solve from the command line, export.

Solving commands print exactly one JSON object on stdout with ``--json`` (the
contract in ``../shared/conventions.md``); progress and logs go to stderr. On
failure they exit non-zero with a one-line error on stderr and, with ``--json``,
``{"error": {"message", "input"}}`` on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from backend.core.errors import InputError

EXIT_INPUT_ERROR = 2


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
    parser = argparse.ArgumentParser(prog="calib-studio", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="open the studio on a demo session of the simulated rig")
    demo.add_argument("--sessions", type=Path, default=Path("sessions"), help="where the demo session is kept")
    demo.add_argument("--fresh", action="store_true", help="rebuild the demo session from scratch")
    _add_serve_args(demo)

    serve = sub.add_parser("serve", help="serve the studio on a folder of sessions")
    serve.add_argument("--sessions", type=Path, required=True, help="folder of sessions")
    _add_serve_args(serve)

    intr = sub.add_parser("intrinsics", help="calibrate a camera from a folder of board images")
    intr.add_argument("images_dir", type=Path)
    intr.add_argument("--board", required=True, help="e.g. checkerboard:9x6:0.025")
    intr.add_argument("--model", default="pinhole-radtan", choices=["pinhole-radtan", "fisheye-equidistant"])
    intr.add_argument("--k3", action="store_true", help="estimate k3 (pinhole-radtan)")
    intr.add_argument("--no-tangential", action="store_true", help="fix p1 = p2 = 0 (pinhole-radtan)")
    intr.add_argument("--fix-aspect", action="store_true", help="keep fx = fy")
    intr.add_argument("--drop-outliers", action="store_true", help="re-solve without outlier views")
    intr.add_argument("--out", type=Path, help="write the ROS camera_info YAML here")
    intr.add_argument("--camera-name", default="camera", help="camera_name in the YAML")
    intr.add_argument("--json", action="store_true", help="print the result as one JSON object")

    export = sub.add_parser("export", help="export an accepted calibration from a session")
    export.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
    export.add_argument("--format", required=True, choices=["camera_info", "opencv", "rig"])
    export.add_argument("--sensor", help="camera name (camera_info, opencv)")
    export.add_argument("--out", type=Path, help="file to write (default: stdout)")
    return parser


def run_intrinsics(args: argparse.Namespace) -> dict[str, Any]:
    from backend.core.boards import BoardSpec
    from backend.exports.ros_camera_info import write_camera_info
    from backend.services.intrinsics import calibrate_folder
    from backend.solvers.intrinsics import IntrinsicsSettings

    settings = IntrinsicsSettings(model=args.model, estimate_k3=args.k3, estimate_tangential=not args.no_tangential,
                                  fix_aspect=args.fix_aspect, drop_outliers=args.drop_outliers)
    result, skipped = calibrate_folder(args.images_dir, BoardSpec.parse(args.board), settings,
                                       _progress_to_stderr(False))
    for item in skipped:
        print(f"warning: {item['message']}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if args.out:
        write_camera_info(args.out, result.camera, args.camera_name)
        print(f"wrote {args.out}", file=sys.stderr)
    summary = result.summary()
    summary["views"] += [{"image": s["input"], "rms_px": None, "used": False} for s in skipped]
    if not args.json:
        cam = result.camera
        print(f"rms {result.rms_px:.4f} px over {sum(v.used for v in result.views)} views\n"
              f"fx {cam.K[0, 0]:.3f} +- {result.std['fx']:.3f}  fy {cam.K[1, 1]:.3f} +- {result.std['fy']:.3f}\n"
              f"cx {cam.K[0, 2]:.3f} +- {result.std['cx']:.3f}  cy {cam.K[1, 2]:.3f} +- {result.std['cy']:.3f}\n"
              f"dist {[round(d, 6) for d in cam.dist]}")
    return summary


def run_export(args: argparse.Namespace) -> None:
    from backend.services.exports import export_text
    from backend.store.session import Session

    session = Session.load(args.session_dir)
    _, text = export_text(session, args.format, args.sensor)
    if args.out:
        args.out.write_text(text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    want_json = getattr(args, "json", False)
    try:
        if args.command in ("demo", "serve"):
            from studio.server import serve

            return serve(args)
        if args.command == "intrinsics":
            summary = run_intrinsics(args)
            if want_json:
                print(json.dumps(summary))
        elif args.command == "export":
            run_export(args)
        return 0
    except InputError as exc:
        print(exc.one_line(), file=sys.stderr)
        if want_json:
            print(json.dumps({"error": exc.to_dict()}))
        return EXIT_INPUT_ERROR
    except KeyboardInterrupt:
        print("error: cancelled", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
