"""Printable calibration targets: a board or V-target spec as a PDF at exact scale."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import Response

from backend.core.errors import InputError, shorten
from backend.exports.target_pdf import DEFAULT_MARGIN_MM, Paper, target_kind, target_sheet

router = APIRouter(tags=["targets"])

BoardQuery = Annotated[str, Query(description="the board's or V-target's spec, e.g. checkerboard:9x6:0.025, "
                                              "charuco:11x8:0.03:0.022:DICT_5X5_100 or "
                                              "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50 (a test field's survey is a "
                                              "file: print it with calib-studio target)", max_length=200)]
PaperQuery = Annotated[Paper, Query(description="auto: the first of a4, letter, a3, a2, a1, a0 the board (or V-target "
                                                "face) fits")]
MarginQuery = Annotated[float, Query(description="white margin at the sheet's edge (mm, at least 5)")]


@router.get("/targets/pdf", response_class=Response, responses={200: {"content": {"application/pdf": {}}}})
def target_pdf(board: BoardQuery, paper: PaperQuery = "auto", margin_mm: MarginQuery = DEFAULT_MARGIN_MM) -> Response:
    """The board on one sheet, or the V-target's two faces a page each, at exactly the spec's size when printed at
    100 % / actual size. A bad spec, paper or margin, a print that does not fit the paper, and a test field (its survey
    is a file on the computer that prints it, so the CLI prints it) are a 422 naming the query's field (``board``,
    ``paper``, ``margin_mm``, as in every route that takes a board spec)."""
    if target_kind(board) == "testfield":
        raise InputError(f"a test field's survey is a file on the computer that prints it, not on this server: print "
                         f"test fields with the CLI (calib-studio target {shorten(board.strip())} --out field.pdf)",
                         "board")
    try:
        sheet = target_sheet(board, paper, margin_mm)
    except InputError as exc:  # VTarget.parse names its spec "target"; here it is the query's "board"
        raise InputError(exc.message, "board" if exc.input == "target" else exc.input, exc.status_code) from None
    return Response(sheet.pdf, media_type="application/pdf",
                    headers={"Content-Disposition": f'attachment; filename="{sheet.filename}"'})
