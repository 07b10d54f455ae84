"""Printable calibration targets: a board spec as a PDF at exact scale."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import Response

from backend.exports.target_pdf import DEFAULT_MARGIN_MM, Paper, board_sheet

router = APIRouter(tags=["targets"])

BoardQuery = Annotated[str, Query(description="the board's spec, e.g. checkerboard:9x6:0.025 or "
                                              "charuco:11x8:0.03:0.022:DICT_5X5_100", max_length=200)]
PaperQuery = Annotated[Paper, Query(description="auto: the first of a4, letter, a3, a2, a1, a0 the board fits")]
MarginQuery = Annotated[float, Query(description="white margin at the sheet's edge (mm, at least 5)")]


@router.get("/targets/pdf", response_class=Response, responses={200: {"content": {"application/pdf": {}}}})
def target_pdf(board: BoardQuery, paper: PaperQuery = "auto", margin_mm: MarginQuery = DEFAULT_MARGIN_MM) -> Response:
    """The board on one sheet, squares at exactly the spec's size when printed at 100 % / actual size. A bad board
    spec, paper or margin, or a board that does not fit the paper, is a 422 naming it (``board``, ``paper``,
    ``margin_mm``: the query's names, as in every route that takes a board spec)."""
    sheet = board_sheet(board, paper, margin_mm)
    return Response(sheet.pdf, media_type="application/pdf",
                    headers={"Content-Disposition": f'attachment; filename="{sheet.filename}"'})
