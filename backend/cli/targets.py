"""``calib-studio target``: a printable calibration board as a PDF at exact scale."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from backend.cli._common import check_outputs
from backend.exports.text_file import write_bytes


def add_parser(sub: argparse._SubParsersAction) -> None:
    target = sub.add_parser("target", help="a printable calibration board as a PDF at exact scale")
    target.add_argument("spec", metavar="SPEC",
                        help="board spec, e.g. checkerboard:9x6:0.025 or charuco:11x8:0.03:0.022:DICT_5X5_100")
    target.add_argument("--out", type=Path, required=True, metavar="board.pdf", help="the PDF to write")
    target.add_argument("--paper", default="auto",
                        help="a4, letter, a3, a2, a1, a0, or auto (default): the first of these the board fits, "
                             "portrait or landscape")
    target.add_argument("--margin-mm", type=float, default=10.0, metavar="MM",
                        help="white margin around the sheet's edge (mm, default 10, at least 5)")
    target.set_defaults(handler=run_target)


def run_target(args: argparse.Namespace) -> None:
    from backend.exports.target_pdf import board_sheet

    check_outputs(args.out)
    sheet = board_sheet(args.spec, args.paper, args.margin_mm)
    write_bytes(args.out, sheet.pdf)
    layout = sheet.layout
    orientation = "landscape" if layout.width_mm > layout.height_mm else "portrait"
    print(f"wrote {args.out}: {layout.paper} {orientation}; print it at 100 % / actual size and check the 100 mm bar",
          file=sys.stderr)
