"""``calib-studio target``: a printable calibration board, wall test field or V-target as a PDF at exact scale."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from backend.cli._common import check_outputs
from backend.exports.text_file import write_bytes


def add_parser(sub: argparse._SubParsersAction) -> None:
    target = sub.add_parser("target", help="a printable calibration board, test field or V-target as a PDF at exact "
                                           "scale")
    target.add_argument("spec", metavar="SPEC",
                        help="target spec: a board (checkerboard:9x6:0.025, charuco:11x8:0.03:0.022:DICT_5X5_100; one "
                             "page), a test field (testfield:DICT_4X4_50:0.15:wall.csv; a page per marker of the "
                             "survey file) or a V-target (vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50; a page per face)")
    target.add_argument("--out", type=Path, required=True, metavar="target.pdf", help="the PDF to write")
    target.add_argument("--paper", default="auto",
                        help="a4, letter, a3, a2, a1, a0, or auto (default): the first of these the board (marker, "
                             "face) fits, portrait or landscape")
    target.add_argument("--margin-mm", type=float, default=10.0, metavar="MM",
                        help="white margin around the sheet's edge (mm, default 10, at least 5)")
    target.set_defaults(handler=run_target)


def run_target(args: argparse.Namespace) -> None:
    from backend.exports.target_pdf import target_sheet

    check_outputs(args.out)
    sheet = target_sheet(args.spec, args.paper, args.margin_mm)
    write_bytes(args.out, sheet.pdf)
    layout = sheet.layout
    orientation = "landscape" if layout.width_mm > layout.height_mm else "portrait"
    pages = "" if sheet.pages == 1 else f", {sheet.pages} pages"
    print(f"wrote {args.out}: {layout.paper} {orientation}{pages}; print it at 100 % / actual size and check the "
          "100 mm bar", file=sys.stderr)
