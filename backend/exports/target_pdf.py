"""Printable calibration targets: a board spec drawn at exact scale on one PDF sheet.

The sheet is a matplotlib figure whose size is the paper's, saved by matplotlib's PDF backend: one figure unit
is one millimetre of paper, and every black square and ChArUco marker cell is a filled vector rectangle (one
compound path, :meth:`BoardSpec.dark_cells_m`), so the squares print at exactly the spec's size at any printer
resolution. Under the board a legend gives the spec string, the square (and marker) size in mm, and a 100 mm
scale bar to check the print with a ruler: printed at 100 % / actual size, the bar is 100 mm.

Sheet coordinates are millimetres from the sheet's top-left corner, x to the right, y down.
"""

from __future__ import annotations

import io
import math
import threading
from dataclasses import dataclass
from typing import Literal

import numpy as np

from backend.core.boards import BoardSpec
from backend.core.errors import InputError, shorten
from backend.core.limits import MAX_TARGET_SQUARES

Paper = Literal["auto", "a4", "letter", "a3", "a2", "a1", "a0"]
PAPERS_MM: dict[str, tuple[float, float]] = {"a4": (210.0, 297.0), "letter": (215.9, 279.4), "a3": (297.0, 420.0),
                                             "a2": (420.0, 594.0), "a1": (594.0, 841.0), "a0": (841.0, 1189.0)}
"""Each paper's (width, height) in portrait (mm), in the order ``auto`` tries them: office sizes first, then the
print shop's (a 9x6 board of 40 mm squares needs a2)."""
MIN_MARGIN_MM = 5.0
"""The narrowest white margin (mm): office printers leave the outer ~4 mm of a sheet blank."""
DEFAULT_MARGIN_MM = 10.0
LEGEND_HEIGHT_MM = 14.0
"""The legend's height under the board (mm), the gap to the board included."""
LEGEND_WIDTH_MM = 180.0
"""The legend's width (mm): the scale bar and the print instruction beside it."""
SCALE_BAR_MM = 100.0
"""The scale bar's length (mm)."""
SCALE_BAR_HEIGHT_MM = 2.5
MM_PER_INCH = 25.4

_RENDER_LOCK = threading.Lock()
"""matplotlib's rcParams are global: one sheet is drawn at a time."""


@dataclass(frozen=True)
class SheetLayout:
    """Where a board goes on its sheet (mm, from the sheet's top-left corner, x right, y down)."""

    paper: str
    """The paper's name (``a4``, ``letter``, ``a3``)."""
    width_mm: float
    height_mm: float
    """The sheet as printed: landscape when the board fits only that way round."""
    board_x_mm: float
    board_y_mm: float
    """The board's outer top-left corner."""
    legend_y_mm: float
    """The top of the legend."""
    margin_mm: float


@dataclass(frozen=True)
class TargetSheet:
    """One printable board: its PDF, the file name to save it under and where it sits on which paper."""

    filename: str
    layout: SheetLayout
    pdf: bytes


def board_sheet(spec: str, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM) -> TargetSheet:
    """The board ``spec`` on one sheet of ``paper`` (``auto``: the first of :data:`PAPERS_MM` it fits) with white
    margins of ``margin_mm`` (mm). :class:`InputError` for a bad spec, paper or margin, and for a board that does not
    fit the paper (naming the sheet it needs and a paper it fits, if any), and, before any drawing, one of more than
    :data:`~backend.core.limits.MAX_TARGET_SQUARES` squares. The CLI, the API and the studio call this."""
    board = BoardSpec.parse(spec)
    if board.n_squares > MAX_TARGET_SQUARES.value():
        raise InputError(f"board {shorten(spec)} has {board.n_squares:,} squares, more than "
                         f"{MAX_TARGET_SQUARES.describe()}: nothing was drawn", "board")
    layout = sheet_layout(board, paper, margin_mm)
    return TargetSheet(target_filename(board), layout, render_sheet(board, layout))


def target_filename(board: BoardSpec) -> str:
    """e.g. ``checkerboard_9x6_25mm.pdf``, ``charuco_11x8_30mm_22mm_DICT_5X5_100.pdf``."""
    size = f"{board.cols}x{board.rows}_{_mm(board.square_m)}mm"
    if board.kind == "checkerboard":
        return f"checkerboard_{size}.pdf"
    return f"charuco_{size}_{_mm(board.marker_m)}mm_{board.dictionary}.pdf"


def sheet_layout(board: BoardSpec, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM) -> SheetLayout:
    """The sheet for ``board``: the paper (portrait unless only landscape fits), the board centred above the
    legend. Refuses (:class:`InputError`) an unknown paper, a margin below :data:`MIN_MARGIN_MM` or not finite, and a
    board that does not fit."""
    if paper != "auto" and paper not in PAPERS_MM:
        raise InputError(f"unknown paper {shorten(paper)}; expected auto, {', '.join(PAPERS_MM)}", "paper")
    if not (math.isfinite(margin_mm) and margin_mm >= MIN_MARGIN_MM):
        raise InputError(f"margin {margin_mm} mm: expected at least {MIN_MARGIN_MM:g} mm (printers leave the sheet's "
                         "edge blank)", "margin_mm")
    board_w, board_h = (1000.0 * v for v in board.size_m)
    need_w = max(board_w, LEGEND_WIDTH_MM) + 2 * margin_mm
    need_h = board_h + LEGEND_HEIGHT_MM + 2 * margin_mm
    candidates = list(PAPERS_MM) if paper == "auto" else [paper]
    for name in candidates:
        if (sheet := _sheet_for(need_w, need_h, PAPERS_MM[name])) is not None:
            sheet_w, sheet_h = sheet
            free_h = sheet_h - 2 * margin_mm - LEGEND_HEIGHT_MM
            board_y = margin_mm + (free_h - board_h) / 2
            return SheetLayout(name, sheet_w, sheet_h, (sheet_w - board_w) / 2, board_y,
                               sheet_h - margin_mm - LEGEND_HEIGHT_MM, margin_mm)
    raise InputError(_does_not_fit(board, paper, margin_mm, need_w, need_h), "paper")


def _does_not_fit(board: BoardSpec, paper: str, margin_mm: float, need_w: float, need_h: float) -> str:
    """Why ``board`` fits no candidate sheet: the size it needs, and a paper or a square size that fits."""
    board_w, board_h = (1000.0 * v for v in board.size_m)
    shown = list(PAPERS_MM)[-1] if paper == "auto" else paper
    message = (f"board {board} is {board_w:.5g} x {board_h:.5g} mm; with {margin_mm:g} mm margins and the "
               f"{LEGEND_HEIGHT_MM:g} mm legend it needs a sheet of {need_w:.5g} x {need_h:.5g} mm (either way round), "
               f"larger than {'the largest paper offered, ' if paper == 'auto' else ''}{shown} "
               "({:g} x {:g} mm)".format(*PAPERS_MM[shown]))
    larger = [name for name in PAPERS_MM if name != paper and _sheet_for(need_w, need_h, PAPERS_MM[name])]
    if larger:
        return f"{message}: print it on {larger[0]}"
    squares = np.array([board_w, board_h]) / (1000.0 * board.square_m)
    sheet = PAPERS_MM[shown]
    largest_mm = max((np.min((np.array([w, h]) - 2 * margin_mm - [0.0, LEGEND_HEIGHT_MM]) / squares)
                      for w, h in (sheet, sheet[::-1]) if w - 2 * margin_mm >= LEGEND_WIDTH_MM), default=0.0)
    if largest_mm < 0.1:
        return f"{message}: margins of {margin_mm:g} mm leave no room on {shown} for the board and its legend"
    return (f"{message}: choose squares of at most {math.floor(largest_mm * 10) / 10:g} mm for {shown}, or have the "
            "board printed on a larger sheet")


def _sheet_for(need_w: float, need_h: float, paper_mm: tuple[float, float]) -> tuple[float, float] | None:
    """The paper's (width, height) (mm) the right way round for a need of ``need_w`` x ``need_h`` mm: portrait if
    it fits so, else landscape, else None."""
    return next(((w, h) for w, h in (paper_mm, paper_mm[::-1]) if need_w <= w + 1e-9 and need_h <= h + 1e-9), None)


def render_sheet(board: BoardSpec, layout: SheetLayout) -> bytes:
    """The PDF of ``board`` on the sheet ``layout`` describes (one page of exactly the sheet's size)."""
    import matplotlib
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    with _RENDER_LOCK, matplotlib.rc_context({"pdf.fonttype": 42}):  # TrueType text: selectable, searchable
        figure = Figure(figsize=(layout.width_mm / MM_PER_INCH, layout.height_mm / MM_PER_INCH))
        axes = figure.add_axes((0.0, 0.0, 1.0, 1.0))
        axes.set_xlim(0.0, layout.width_mm)
        axes.set_ylim(layout.height_mm, 0.0)  # y down the sheet
        axes.set_axis_off()
        cells = 1000.0 * board.dark_cells_m() + [layout.board_x_mm, layout.board_y_mm] * 2
        cells = np.concatenate([cells, _scale_bar(layout)])
        corners = cells[:, [0, 1, 2, 1, 2, 3, 0, 3, 0, 1]].reshape(-1, 2)  # each rectangle closed, one winding
        codes = np.tile([MplPath.MOVETO, MplPath.LINETO, MplPath.LINETO, MplPath.LINETO, MplPath.CLOSEPOLY],
                        len(cells))
        axes.add_patch(PathPatch(MplPath(corners, codes), facecolor="black", edgecolor="none", linewidth=0))
        _legend(axes, board, layout)
        buffer = io.BytesIO()
        figure.savefig(buffer, format="pdf", metadata={"Title": str(board), "Creator": "Calibration Studio",
                                                       "CreationDate": None})
    return buffer.getvalue()


def _scale_bar(layout: SheetLayout) -> np.ndarray:
    """Rectangles (mm) of the scale bar at the legend's left edge and its 10 mm ticks above it."""
    x0, bar_y = layout.margin_mm, layout.legend_y_mm + LEGEND_HEIGHT_MM - SCALE_BAR_HEIGHT_MM
    ticks = np.clip(x0 + np.arange(0.0, SCALE_BAR_MM + 1, 10.0)[:, None] + [-0.15, 0.15], x0, x0 + SCALE_BAR_MM)
    tick_cells = np.column_stack([ticks[:, 0], np.full(len(ticks), bar_y - 1.2), ticks[:, 1], np.full(len(ticks),
                                                                                                     bar_y)])
    return np.vstack([[x0, bar_y, x0 + SCALE_BAR_MM, bar_y + SCALE_BAR_HEIGHT_MM], tick_cells])


def _legend(axes, board: BoardSpec, layout: SheetLayout) -> None:
    """The spec, the sizes in mm and the print instruction beside the scale bar."""
    board_w, board_h = (1000.0 * v for v in board.size_m)
    if board.kind == "checkerboard":
        sizes = (f"{board.cols} x {board.rows} inner corners, {board.cols + 1} x {board.rows + 1} squares of "
                 f"{_mm(board.square_m)} mm")
    else:
        sizes = (f"{board.cols} x {board.rows} squares of {_mm(board.square_m)} mm, ArUco markers of "
                 f"{_mm(board.marker_m)} mm ({board.dictionary})")
    x0, top = layout.margin_mm, layout.legend_y_mm
    axes.text(x0, top + 2.0, str(board), family="monospace", weight="bold", size=9, va="top")
    axes.text(x0, top + 6.2, f"{sizes}; board {board_w:g} x {board_h:g} mm", size=7, va="top")
    axes.text(x0 + SCALE_BAR_MM + 2.0, top + LEGEND_HEIGHT_MM - SCALE_BAR_HEIGHT_MM / 2,
              "<- print at 100 % / actual size (no 'fit to page'); check: this bar is 100 mm", size=7, va="center")


def _mm(metres: float) -> str:
    """A length in metres as millimetres for a label (``0.025`` -> ``25``, ``0.0254`` -> ``25.4``)."""
    return f"{round(1000.0 * metres, 3):g}"
