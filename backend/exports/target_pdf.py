"""Printable calibration targets at exact scale as PDF: a board on one sheet, a wall test field's markers one a page,
a V-target's two faces one a page.

Each page is a matplotlib figure whose size is the paper's, saved by matplotlib's PDF backend: one figure unit is one
millimetre of paper, and every black square and marker cell is a filled vector rectangle (one compound path a page),
so it prints at exactly the spec's size at any printer resolution. What a page prints is an :class:`Artwork`: the
exact-scale print and any marks around it. Under it a legend gives the spec string, the sizes in mm and a 100 mm
scale bar to check the print with a ruler: printed at 100 % / actual size, the bar is 100 mm.

- A board (``checkerboard:...``, ``charuco:...``, :mod:`backend.core.boards`): one sheet of its black squares and
  ChArUco markers (:meth:`BoardSpec.dark_cells_m`).
- A test field (``testfield:DICT:MARKER:SURVEY``, :mod:`backend.core.test_field`): a page per surveyed marker, in the
  survey's order: the marker at ``MARKER`` side (its black border included, as OpenCV draws it), a white quiet zone
  of one marker cell around it, then four short ticks on its centre lines pointing at its centre, for the surveyor,
  and its id and dictionary under it.
- A V-target (``vtarget:...``, :mod:`backend.core.v_target`): a page per face, face 0 (the left plate) first: the
  face's whole ``W x H`` print, outlined by a hairline inside its edge (cut along the line's outer edge), its markers
  upright at :attr:`VTarget.marker_centres_print`; the legend names the face and its ridge edge.

Every page of a PDF is on the same paper: the first of :data:`PAPERS_MM` the print, its marks and the legend fit, or
the one asked for. A print that does not fit is refused with the sheet it needs and a paper, or a smaller size, that
fits; nothing is tiled over several sheets (a print shop prints a large board or face on one sheet).

Sheet coordinates are millimetres from the sheet's top-left corner, x to the right, y down.
"""

from __future__ import annotations

import io
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from backend.core.boards import BoardSpec
from backend.core.errors import InputError, shorten
from backend.core.limits import MAX_TARGET_SQUARES
from backend.core.markers import marker_cells, marker_image
from backend.core.test_field import TestField
from backend.core.v_target import VTarget

Paper = Literal["auto", "a4", "letter", "a3", "a2", "a1", "a0"]
PAPERS_MM: dict[str, tuple[float, float]] = {"a4": (210.0, 297.0), "letter": (215.9, 279.4), "a3": (297.0, 420.0),
                                             "a2": (420.0, 594.0), "a1": (594.0, 841.0), "a0": (841.0, 1189.0)}
"""Each paper's (width, height) in portrait (mm), in the order ``auto`` tries them: office sizes first, then the
print shop's (a 9x6 board of 40 mm squares needs a2)."""
TARGET_KINDS = ("checkerboard", "charuco", "testfield", "vtarget")
"""What a spec's first field may be."""
MIN_MARGIN_MM = 5.0
"""The narrowest white margin (mm): office printers leave the outer ~4 mm of a sheet blank."""
DEFAULT_MARGIN_MM = 10.0
LEGEND_HEIGHT_MM = 14.0
"""The legend's height under the print (mm), the gap to the print included."""
LEGEND_WIDTH_MM = 180.0
"""The legend's width (mm): the scale bar and the print instruction beside it."""
SCALE_BAR_MM = 100.0
"""The scale bar's length (mm)."""
SCALE_BAR_HEIGHT_MM = 2.5
TICK_MM = 6.0
"""Length of a test-field marker's centre ticks (mm), outside its quiet zone."""
TICK_WIDTH_MM = 0.3
CAPTION_MM = 4.0
"""Room for a test-field marker's id and dictionary under its lower tick (mm), kept on every side so that the marker
is centred."""
FACE_OUTLINE_MM = 0.2
"""Width of the hairline just inside a V-target face's edge (mm)."""
MM_PER_INCH = 25.4

_RENDER_LOCK = threading.Lock()
"""matplotlib's rcParams are global: one PDF is drawn at a time."""


@dataclass(frozen=True)
class Footprint:
    """The room a PDF's print takes on its sheet (every page's the same), and how a refusal names and shrinks it."""

    what: str
    """The print as a message names it: ``board checkerboard:9x6:0.025``, ``each face of vtarget:...``."""
    noun: str
    """``board``, ``marker``, ``face``."""
    size_mm: tuple[float, float]
    """The exact-scale print's width and height (mm): the board's outer edge, the marker's, the face's."""
    unit: str
    """What a refusal says to make smaller when no paper fits: ``squares``, ``markers``, ``plates``."""
    unit_mm: tuple[float, ...]
    """That unit's size now (mm): a square's side, a marker's, a plate's width and height; it scales the print."""
    quiet: float = 0.0
    """White room on each side of the print as a fraction of its size (a test-field marker's quiet zone)."""
    marks_mm: float = 0.0
    """Room for marks on each side of the print beyond the quiet zone (mm)."""
    surround: str = ""
    """The quiet zone and marks as a refusal names them (empty: none)."""

    @property
    def outer_mm(self) -> tuple[float, float]:
        """The print, its quiet zone and marks (mm)."""
        width, height = (side * (1 + 2 * self.quiet) + 2 * self.marks_mm for side in self.size_mm)
        return width, height


@dataclass(frozen=True)
class Artwork:
    """What one page prints (mm, from the exact-scale print's top-left corner, x right, y down)."""

    cells_mm: np.ndarray
    """(N, 4) black rectangles ``[x0, y0, x1, y1]``: the print's and its marks'."""
    title: str
    """The legend's first line: the spec."""
    detail: str
    """The legend's second line: what the page holds, sizes in mm."""
    labels: tuple[tuple[float, float, str], ...] = ()
    """Small text centred below each ``(x, y)`` (a test-field marker's id)."""


@dataclass(frozen=True)
class SheetLayout:
    """Where the print goes on its sheet (mm, from the sheet's top-left corner, x right, y down)."""

    paper: str
    """The paper's name (``a4``, ``letter``, ``a3``, ...)."""
    width_mm: float
    height_mm: float
    """The sheet as printed: landscape when the print fits only that way round."""
    print_x_mm: float
    print_y_mm: float
    """The exact-scale print's top-left corner."""
    legend_y_mm: float
    """The top of the legend."""
    margin_mm: float


@dataclass(frozen=True)
class TargetSheet:
    """One printable target: its PDF, the file name to save it under, where it sits on which paper and its pages."""

    filename: str
    layout: SheetLayout
    pdf: bytes
    pages: int


def target_kind(spec: str) -> str:
    """The kind a target spec names (one of :data:`TARGET_KINDS`), before anything of it is parsed or read;
    :class:`InputError` for another."""
    kind = spec.strip().split(":", 1)[0]
    if kind not in TARGET_KINDS:
        raise InputError(f"unknown target kind {shorten(kind)} in {shorten(spec)}; expected checkerboard, charuco, "
                         "testfield or vtarget", "board")
    return kind


def target_sheet(spec: str, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM,
                 folder: Path | None = None) -> TargetSheet:
    """The PDF of any target spec: :func:`board_sheet`, :func:`field_sheet` (its survey read from the session
    ``folder`` if given) or :func:`v_target_sheet`."""
    kind = target_kind(spec)
    if kind == "testfield":
        return field_sheet(spec, paper, margin_mm, folder)
    return (v_target_sheet if kind == "vtarget" else board_sheet)(spec, paper, margin_mm)


def board_sheet(spec: str, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM) -> TargetSheet:
    """The board ``spec`` on one sheet of ``paper`` (``auto``: the first of :data:`PAPERS_MM` it fits) with white
    margins of ``margin_mm`` (mm). :class:`InputError` for a bad spec, paper or margin, and for a board that does not
    fit the paper (naming the sheet it needs and a paper it fits, if any), and, before any drawing, one of more than
    :data:`~backend.core.limits.MAX_TARGET_SQUARES` squares. The CLI, the API and the studio call this."""
    board = BoardSpec.parse(spec)
    if board.n_squares > MAX_TARGET_SQUARES.value():
        raise InputError(f"board {shorten(spec)} has {board.n_squares:,} squares, more than "
                         f"{MAX_TARGET_SQUARES.describe()}: nothing was drawn", "board")
    board_w, board_h = (1000.0 * v for v in board.size_m)
    footprint = Footprint(f"board {board}", "board", (board_w, board_h), "squares", (1000.0 * board.square_m,))
    layout = sheet_layout(footprint, paper, margin_mm)
    if board.kind == "checkerboard":
        sizes = (f"{board.cols} x {board.rows} inner corners, {board.cols + 1} x {board.rows + 1} squares of "
                 f"{_mm(board.square_m)} mm")
    elif board.kind == "aprilgrid":
        sizes = (f"{board.cols} x {board.rows} tags (tag36h11, ids 0 to {board.cols * board.rows - 1} from the bottom "
                 f"left) of {_mm(board.square_m)} mm, gaps of {_mm(board.gap_m)} mm (spacing {board.spacing:g})")
    else:
        sizes = (f"{board.cols} x {board.rows} squares of {_mm(board.square_m)} mm, ArUco markers of "
                 f"{_mm(board.marker_m)} mm ({board.dictionary})")
    page = Artwork(1000.0 * board.dark_cells_m(), str(board), f"{sizes}; board {board_w:g} x {board_h:g} mm")
    return TargetSheet(board_filename(board), layout, render_pages([page], layout), 1)


def field_sheet(spec: str, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM,
                folder: Path | None = None) -> TargetSheet:
    """A page per marker of the test field ``spec`` (reading its survey file, a session's from its ``folder`` if
    given), in the survey's order, on ``paper`` with margins of ``margin_mm`` (mm), as :func:`board_sheet` does a
    board. :class:`InputError` for a bad spec or survey file (naming it), paper or margin, and for markers that do
    not fit the paper."""
    field = TestField.parse(spec, folder)
    side_mm = 1000.0 * field.marker_m
    quiet = 1 / len(marker_image(field.dictionary, 0, 1))  # one of the marker's cells a side (its border's included)
    footprint = Footprint(f"each marker of {field}", "marker", (side_mm, side_mm), "markers", (side_mm,), quiet,
                          TICK_MM + CAPTION_MM, "its quiet zone of one cell, the centre ticks and the id")
    layout = sheet_layout(footprint, paper, margin_mm)
    title = f"testfield:{field.dictionary}:{field.marker_m:g}:{field.survey.name}"  # the survey's folder left out
    ticks = _centre_ticks(side_mm, quiet * side_mm)
    label_y = side_mm + quiet * side_mm + TICK_MM + 1.0
    pages = [Artwork(np.concatenate([marker_cells(field.dictionary, marker_id, side_mm, (0.0, 0.0)), ticks]), title,
                     f"marker {marker_id} ({k + 1} of {len(field.ids)} in the survey), {_mm(field.marker_m)} mm, its "
                     f"black border included; surveyed centre {x:.3f}, {y:.3f}, {z:.3f} m",
                     ((side_mm / 2, label_y, f"id {marker_id}   {field.dictionary}"),))
             for k, (marker_id, (x, y, z)) in enumerate(zip(field.ids, field.centres_m, strict=True))]
    filename = f"testfield_{field.dictionary}_{_mm(field.marker_m)}mm_{field.survey.stem}.pdf"
    return TargetSheet(filename, layout, render_pages(pages, layout), len(pages))


def v_target_sheet(spec: str, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM) -> TargetSheet:
    """The V-target ``spec``'s two faces, face 0 (the left plate) then face 1, a page each on ``paper`` with margins
    of ``margin_mm`` (mm), as :func:`board_sheet` does a board. :class:`InputError` for a bad spec, paper or margin,
    and for faces that do not fit the paper."""
    target = VTarget.parse(spec)
    face_w, face_h = 1000.0 * target.width_m, 1000.0 * target.height_m
    footprint = Footprint(f"each face of {target}", "face", (face_w, face_h), "plates", (face_w, face_h))
    layout = sheet_layout(footprint, paper, margin_mm)
    side_mm, line = 1000.0 * target.marker_m, FACE_OUTLINE_MM
    outline = np.array([[0.0, 0.0, face_w, line], [0.0, face_h - line, face_w, face_h], [0.0, 0.0, line, face_h],
                        [face_w - line, 0.0, face_w, face_h]])
    pages = []
    for face, (plate, ridge) in enumerate((("left", "right"), ("right", "left"))):
        ids = target.marker_ids[face * target.markers_per_face: (face + 1) * target.markers_per_face]
        markers = [marker_cells(target.dictionary, marker_id, side_mm, 1000.0 * centre - side_mm / 2)
                   for marker_id, centre in zip(ids, target.marker_centres_print, strict=True)]
        pages.append(Artwork(np.concatenate([outline, *markers]), str(target),
                             f"face {face}, the {plate} plate: its {ridge} edge is the ridge; {face_w:g} x {face_h:g} "
                             f"mm to the outline's outer edge; markers {ids[0]} to {ids[-1]} of "
                             f"{_mm(target.marker_m)} mm ({target.dictionary})"))
    filename = (f"vtarget_{_mm(target.width_m)}x{_mm(target.height_m)}mm_{target.angle_deg:g}deg_"
                f"{target.cols}x{target.rows}_{_mm(target.marker_m)}mm_{target.dictionary}.pdf")
    return TargetSheet(filename, layout, render_pages(pages, layout), len(pages))


def board_filename(board: BoardSpec) -> str:
    """e.g. ``checkerboard_9x6_25mm.pdf``, ``charuco_11x8_30mm_22mm_DICT_5X5_100.pdf``."""
    size = f"{board.cols}x{board.rows}_{_mm(board.square_m)}mm"
    if board.kind == "checkerboard":
        return f"checkerboard_{size}.pdf"
    if board.kind == "aprilgrid":
        return f"aprilgrid_{size}_{board.spacing:g}.pdf"
    return f"charuco_{size}_{_mm(board.marker_m)}mm_{board.dictionary}.pdf"


def sheet_layout(footprint: Footprint, paper: str = "auto", margin_mm: float = DEFAULT_MARGIN_MM) -> SheetLayout:
    """The sheet for a print of ``footprint``: the paper (portrait unless only landscape fits), the print centred
    above the legend. Refuses (:class:`InputError`) an unknown paper, a margin below :data:`MIN_MARGIN_MM` or not
    finite, and a print that does not fit."""
    if paper != "auto" and paper not in PAPERS_MM:
        raise InputError(f"unknown paper {shorten(paper)}; expected auto, {', '.join(PAPERS_MM)}", "paper")
    if not (math.isfinite(margin_mm) and margin_mm >= MIN_MARGIN_MM):
        raise InputError(f"margin {margin_mm} mm: expected at least {MIN_MARGIN_MM:g} mm (printers leave the sheet's "
                         "edge blank)", "margin_mm")
    outer_w, outer_h = footprint.outer_mm
    need_w = max(outer_w, LEGEND_WIDTH_MM) + 2 * margin_mm
    need_h = outer_h + LEGEND_HEIGHT_MM + 2 * margin_mm
    candidates = list(PAPERS_MM) if paper == "auto" else [paper]
    for name in candidates:
        if (sheet := _sheet_for(need_w, need_h, PAPERS_MM[name])) is not None:
            sheet_w, sheet_h = sheet
            print_w, print_h = footprint.size_mm
            free_h = sheet_h - 2 * margin_mm - LEGEND_HEIGHT_MM
            return SheetLayout(name, sheet_w, sheet_h, (sheet_w - print_w) / 2, margin_mm + (free_h - print_h) / 2,
                               sheet_h - margin_mm - LEGEND_HEIGHT_MM, margin_mm)
    raise InputError(_does_not_fit(footprint, paper, margin_mm, need_w, need_h), "paper")


def _does_not_fit(footprint: Footprint, paper: str, margin_mm: float, need_w: float, need_h: float) -> str:
    """Why the print fits no candidate sheet: the size it needs, and a paper or a smaller unit that fits."""
    print_w, print_h = footprint.size_mm
    shown = list(PAPERS_MM)[-1] if paper == "auto" else paper
    outer_w, outer_h = footprint.outer_mm
    surround = f"{footprint.surround} ({outer_w:.5g} x {outer_h:.5g} mm), " if footprint.surround else ""
    message = (f"{footprint.what} is {print_w:.5g} x {print_h:.5g} mm; with {surround}{margin_mm:g} mm margins and the "
               f"{LEGEND_HEIGHT_MM:g} mm legend it needs a sheet of {need_w:.5g} x {need_h:.5g} mm (either way round), "
               f"larger than {'the largest paper offered, ' if paper == 'auto' else ''}{shown} "
               "({:g} x {:g} mm)".format(*PAPERS_MM[shown]))
    larger = [name for name in PAPERS_MM if name != paper and _sheet_for(need_w, need_h, PAPERS_MM[name])]
    if larger:
        return f"{message}: print it on {larger[0]}"
    units = np.array(footprint.size_mm) * (1 + 2 * footprint.quiet) / footprint.unit_mm[0]
    sheet = PAPERS_MM[shown]
    largest_mm = max((np.min((np.array([w, h]) - 2 * margin_mm - [0.0, LEGEND_HEIGHT_MM] - 2 * footprint.marks_mm)
                             / units) for w, h in (sheet, sheet[::-1]) if w - 2 * margin_mm >= LEGEND_WIDTH_MM),
                     default=0.0)
    if largest_mm < 0.1:
        return (f"{message}: margins of {margin_mm:g} mm leave no room on {shown} for the {footprint.noun} and its "
                "legend")
    sizes = " x ".join(f"{math.floor(largest_mm * unit / footprint.unit_mm[0] * 10) / 10:g}"
                       for unit in footprint.unit_mm)
    return (f"{message}: choose {footprint.unit} of at most {sizes} mm for {shown}, or have the {footprint.noun} "
            "printed on a larger sheet")


def _sheet_for(need_w: float, need_h: float, paper_mm: tuple[float, float]) -> tuple[float, float] | None:
    """The paper's (width, height) (mm) the right way round for a need of ``need_w`` x ``need_h`` mm: portrait if
    it fits so, else landscape, else None."""
    return next(((w, h) for w, h in (paper_mm, paper_mm[::-1]) if need_w <= w + 1e-9 and need_h <= h + 1e-9), None)


def _centre_ticks(side_mm: float, quiet_mm: float) -> np.ndarray:
    """(4, 4) rectangles (mm, from a marker's top-left corner) of the ticks on its centre lines beyond the quiet zone,
    pointing at its centre: above, below, left and right of it."""
    mid, half = side_mm / 2, TICK_WIDTH_MM / 2
    before, after = -quiet_mm - TICK_MM, side_mm + quiet_mm  # where the ticks above/left and below/right start
    vertical = np.array([[mid - half, start, mid + half, start + TICK_MM] for start in (before, after)])
    return np.concatenate([vertical, vertical[:, [1, 0, 3, 2]]])  # then the same across the marker: left and right


def render_pages(pages: Sequence[Artwork], layout: SheetLayout) -> bytes:
    """The PDF of ``pages``, each on a page of exactly the sheet's size with its print where ``layout`` says, its
    legend and scale bar below. The document's title is the first page's."""
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    buffer = io.BytesIO()
    metadata = {"Title": pages[0].title, "Creator": "Calibration Studio", "CreationDate": None}
    # TrueType text: selectable, searchable (read when the document is closed, so the context closes after it)
    with _RENDER_LOCK, matplotlib.rc_context({"pdf.fonttype": 42}), PdfPages(buffer, metadata=metadata) as document:
        for page in pages:
            figure = Figure(figsize=(layout.width_mm / MM_PER_INCH, layout.height_mm / MM_PER_INCH))
            axes = figure.add_axes((0.0, 0.0, 1.0, 1.0))
            axes.set_xlim(0.0, layout.width_mm)
            axes.set_ylim(layout.height_mm, 0.0)  # y down the sheet
            axes.set_axis_off()
            cells = page.cells_mm + [layout.print_x_mm, layout.print_y_mm] * 2
            cells = np.concatenate([cells, _scale_bar(layout)])
            corners = cells[:, [0, 1, 2, 1, 2, 3, 0, 3, 0, 1]].reshape(-1, 2)  # each rectangle closed, one winding
            codes = np.tile([MplPath.MOVETO, MplPath.LINETO, MplPath.LINETO, MplPath.LINETO, MplPath.CLOSEPOLY],
                            len(cells))
            axes.add_patch(PathPatch(MplPath(corners, codes), facecolor="black", edgecolor="none", linewidth=0))
            for x, y, text in page.labels:
                axes.text(layout.print_x_mm + x, layout.print_y_mm + y, text, size=6, ha="center", va="top",
                          parse_math=False)
            _legend(axes, page, layout)
            document.savefig(figure)
    return buffer.getvalue()


def _scale_bar(layout: SheetLayout) -> np.ndarray:
    """Rectangles (mm) of the scale bar at the legend's left edge and its 10 mm ticks above it."""
    x0, bar_y = layout.margin_mm, layout.legend_y_mm + LEGEND_HEIGHT_MM - SCALE_BAR_HEIGHT_MM
    ticks = np.clip(x0 + np.arange(0.0, SCALE_BAR_MM + 1, 10.0)[:, None] + [-0.15, 0.15], x0, x0 + SCALE_BAR_MM)
    tick_cells = np.column_stack([ticks[:, 0], np.full(len(ticks), bar_y - 1.2), ticks[:, 1], np.full(len(ticks),
                                                                                                     bar_y)])
    return np.vstack([[x0, bar_y, x0 + SCALE_BAR_MM, bar_y + SCALE_BAR_HEIGHT_MM], tick_cells])


def _legend(axes, page: Artwork, layout: SheetLayout) -> None:
    """The page's title and detail, and the print instruction beside the scale bar."""
    x0, top = layout.margin_mm, layout.legend_y_mm
    axes.text(x0, top + 2.0, page.title, family="monospace", weight="bold", size=9, va="top", parse_math=False)
    axes.text(x0, top + 6.2, page.detail, size=7, va="top", parse_math=False)
    axes.text(x0 + SCALE_BAR_MM + 2.0, top + LEGEND_HEIGHT_MM - SCALE_BAR_HEIGHT_MM / 2,
              "<- print at 100 % / actual size (no 'fit to page'); check: this bar is 100 mm", size=7, va="center")


def _mm(metres: float) -> str:
    """A length in metres as millimetres for a label (``0.025`` -> ``25``, ``0.0254`` -> ``25.4``)."""
    return f"{round(1000.0 * metres, 3):g}"
