"""``calib-studio rig``, ``export``, ``report``: a session's fused rig, its exports and its calibration report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import check_outputs, prints_summary
from backend.exports.text_file import write_text


def _names(value: str) -> list[str]:
    """``a,b`` as ``["a", "b"]`` (empty parts dropped)."""
    return [name for name in value.split(",") if name]


def add_parser(sub: argparse._SubParsersAction) -> None:
    from backend.exports.formats import CONVENTION_FORMATS, CONVENTIONS, EXPORT_FORMATS

    rig = sub.add_parser("rig", help="the session's rig as one fused tree: every accepted edge's residual, the loops")
    rig.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
    rig.add_argument("--json", action="store_true", help="print the tree as one JSON object")
    rig.set_defaults(handler=prints_summary(run_rig))

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
    export.add_argument("--sensor", help="camera name (camera_info, opencv, camera-json, mrcal)")
    export.add_argument("--out", type=Path, help="file to write (default: stdout)")
    export.set_defaults(handler=run_export)

    report = sub.add_parser("report", help="the session's calibration report: one self-contained HTML file")
    report.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
    report.add_argument("--out", type=Path, required=True, metavar="report.html", help="the HTML file to write")
    report.set_defaults(handler=run_report)


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


def run_export(args: argparse.Namespace) -> None:
    from backend.services.exports import export_text
    from backend.store.session import Session

    check_outputs(args.out)
    session = Session.load(args.session_dir)
    _, text = export_text(session, args.format, args.sensor, convention=args.convention, cameras=args.cameras)
    if args.out:
        write_text(args.out, text)
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)


def run_report(args: argparse.Namespace) -> None:
    """Write the session's calibration report (HTML, plots and CSS inline) to ``--out``."""
    from backend.services.report import render_report
    from backend.store.session import Session

    check_outputs(args.out)
    write_text(args.out, render_report(Session.load(args.session_dir)))
    print(f"wrote {args.out}", file=sys.stderr)
