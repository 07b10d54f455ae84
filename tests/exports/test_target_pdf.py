"""Printable targets: the PDF rasterised by pdfium at a known DPI, the board found by OpenCV and measured in mm.

The squares (and ChArUco markers) must print at the spec's size within 0.2 mm, the page must be the paper's size,
the spec and the print instruction must be on the sheet as text, and the scale bar must be 100 mm. The CLI, the API
and the studio's session step (tests/browser/test_intrinsics.py, beside the studio it shares) serve the same sheet.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pypdfium2 as pdfium
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.exports.target_pdf import PAPERS_MM, board_sheet
from studio import cli
from tests.conftest import cli_in_process

DPI = 150
MM_PER_PX = 25.4 / DPI
TOLERANCE_MM = 0.2
CHECKERBOARD = "checkerboard:9x6:0.025"
CHARUCO = "charuco:11x8:0.03:0.022:DICT_5X5_100"


def rasterise(pdf: bytes) -> tuple[np.ndarray, tuple[float, float], str]:
    """The only page of ``pdf``: grayscale pixels at :data:`DPI`, its size (mm) and its text."""
    document = pdfium.PdfDocument(pdf)
    assert len(document) == 1
    page = document[0]
    width_pt, height_pt = page.get_size()
    pixels = page.render(scale=DPI / 72, grayscale=True).to_numpy()
    text = page.get_textpage().get_text_range()
    return (pixels if pixels.ndim == 2 else pixels[..., 0]), (width_pt / 72 * 25.4, height_pt / 72 * 25.4), text


def scale_bar_mm(pixels: np.ndarray) -> float:
    """Length (mm) of the longest horizontal black bar on the sheet, from the ink along its middle row (sub-pixel:
    the anti-aliased ends count by their coverage)."""
    dark = pixels < 64  # a row on the border of two rows of squares is grey all along (half of each)
    best = (0, 0, 0)  # run length, row, start column
    for row in np.nonzero(dark.any(axis=1))[0]:
        edges = np.flatnonzero(np.diff(np.concatenate([[0], dark[row].astype(np.int8), [0]])))
        starts, ends = edges[::2], edges[1::2]
        k = int(np.argmax(ends - starts))
        best = max(best, (int(ends[k] - starts[k]), int(row), int(starts[k])))
    length, _, start = best
    middle = int(np.nonzero(dark[:, start: start + length].all(axis=1))[0].mean())
    ink = 1.0 - pixels[middle, max(start - 3, 0): start + length + 3] / 255.0
    return float(ink.sum()) * MM_PER_PX


@pytest.mark.parametrize(("spec", "paper", "sheet_mm"), [
    (CHECKERBOARD, "auto", (297.0, 210.0)),   # a4 only fits it landscape
    ("checkerboard:7x5:0.02", "letter", (215.9, 279.4)),
    ("checkerboard:6x4:0.0254", "a3", (297.0, 420.0)),
])
@pytest.mark.slow
def test_checkerboard_prints_at_exact_scale(spec: str, paper: str, sheet_mm: tuple[float, float]) -> None:
    board = BoardSpec.parse(spec)
    sheet = board_sheet(spec, paper)
    assert b"/Subtype /Image" not in sheet.pdf, "the board must be vector squares, not a raster"
    pixels, size_mm, text = rasterise(sheet.pdf)
    np.testing.assert_allclose(size_mm, sheet_mm, atol=0.01)

    found, corners = cv2.findChessboardCornersSB(pixels, board.corner_grid,
                                                 flags=cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE)
    assert found, f"OpenCV found no {board.corner_grid} checkerboard on the sheet"
    grid = corners.reshape(board.rows, board.cols, 2)
    along_rows = np.linalg.norm(grid[:, -1] - grid[:, 0], axis=1) / (board.cols - 1) * MM_PER_PX
    along_cols = np.linalg.norm(grid[-1] - grid[0], axis=1) / (board.rows - 1) * MM_PER_PX
    square_mm = 1000 * board.square_m
    np.testing.assert_allclose(along_rows, square_mm, atol=TOLERANCE_MM)
    np.testing.assert_allclose(along_cols, square_mm, atol=TOLERANCE_MM)

    assert spec in text, text
    assert f"squares of {square_mm:g} mm" in text, text
    assert "print at 100 % / actual size" in text and "this bar is 100 mm" in text, text
    assert abs(scale_bar_mm(pixels) - 100.0) < TOLERANCE_MM


@pytest.mark.parametrize(("spec", "paper"), [(CHARUCO, "a3"), ("charuco:5x7:0.0254:0.019:DICT_4X4_50", "auto")])
def test_charuco_prints_at_exact_scale(spec: str, paper: str) -> None:
    board = BoardSpec.parse(spec)
    sheet = board_sheet(spec, paper)
    assert b"/Subtype /Image" not in sheet.pdf
    pixels, size_mm, text = rasterise(sheet.pdf)
    np.testing.assert_allclose(sorted(size_mm), sorted(PAPERS_MM["a3" if paper == "a3" else "a4"]), atol=0.01)

    charuco = board.charuco_board()
    markers = cv2.aruco.DetectorParameters()
    markers.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.CharucoDetector(charuco, cv2.aruco.CharucoParameters(), markers)
    corners, ids, marker_corners, marker_ids = detector.detectBoard(pixels)
    assert sorted(marker_ids.ravel()) == sorted(charuco.getIds().ravel()), "every marker found, with its own id"
    assert ids is not None and len(ids) == board.n_corners
    # The corners against the board's own (m): an affine fit whose scale is the printed size; it must fit them all.
    board_xy = np.column_stack([charuco.getChessboardCorners()[ids.ravel(), :2], np.ones(len(ids))])
    fit, *_ = np.linalg.lstsq(board_xy, corners.reshape(-1, 2), rcond=None)
    assert np.abs(board_xy @ fit - corners.reshape(-1, 2)).max() * MM_PER_PX < TOLERANCE_MM
    axes_mm = np.linalg.norm(fit[:2], axis=1) * board.square_m * MM_PER_PX  # one square along x and along y
    np.testing.assert_allclose(axes_mm, 1000 * board.square_m, atol=TOLERANCE_MM)
    sides = np.linalg.norm(np.array(marker_corners) - np.roll(np.array(marker_corners), 1, axis=2), axis=-1)
    assert abs(sides.mean() * MM_PER_PX - 1000 * board.marker_m) < TOLERANCE_MM

    assert spec in text and f"markers of {1000 * board.marker_m:g} mm" in text, text
    assert abs(scale_bar_mm(pixels) - 100.0) < TOLERANCE_MM


def test_vector_cells_are_the_board_opencv_renders() -> None:
    """The rectangles drawn on the sheet, rasterised at a scale where every cell edge is a whole pixel, are
    exactly :meth:`BoardSpec.render`'s image (OpenCV's own for ChArUco)."""
    for spec, px_per_square in ((CHECKERBOARD, 60), (CHARUCO, 210)):
        board = BoardSpec.parse(spec)
        expected = board.render(px_per_square)
        drawn = np.full_like(expected, 255)
        for x0, y0, x1, y1 in np.rint(board.dark_cells_m() * px_per_square / board.square_m).astype(int):
            drawn[y0:y1, x0:x1] = 0
        assert np.array_equal(drawn, expected), spec


def test_a_board_that_does_not_fit_is_refused_with_the_size_it_needs() -> None:
    with pytest.raises(InputError) as refused:
        board_sheet(CHARUCO, "a4")
    assert refused.value.input == "paper"
    assert "330 x 240 mm" in refused.value.message and "350 x 274 mm" in refused.value.message
    assert "larger than a4" in refused.value.message and "print it on a3" in refused.value.message
    assert board_sheet(CHARUCO).layout.paper == "a3"  # auto takes the first paper it fits

    with pytest.raises(InputError) as too_big:
        board_sheet("checkerboard:12x9:0.1")
    message = too_big.value.message
    assert "1320 x 1034 mm" in message and "the largest paper offered, a0" in message
    largest_mm = float(re.search(r"squares of at most ([\d.]+) mm for a0", message).group(1))
    board_sheet(f"checkerboard:12x9:{largest_mm / 1000}", "a0")  # the square size it suggests does fit
    with pytest.raises(InputError):
        board_sheet(f"checkerboard:12x9:{(largest_mm + 0.2) / 1000}", "a0")
    with pytest.raises(InputError, match="margins of 500 mm leave no room on a0"):
        board_sheet(CHECKERBOARD, margin_mm=500.0)


@pytest.mark.parametrize(("spec", "paper", "margin_mm", "input_name"), [
    ("checkerboard:9x6", "auto", 10.0, "board"),
    ("charuco:11x8:0.03:0.022:DICT_NOPE", "auto", 10.0, "board"),
    (CHECKERBOARD, "a5", 10.0, "paper"),
    (CHECKERBOARD, "auto", 2.0, "margin_mm"),
    (CHECKERBOARD, "auto", float("nan"), "margin_mm"),
])
def test_bad_input_is_refused_by_name(spec: str, paper: str, margin_mm: float, input_name: str) -> None:
    with pytest.raises(InputError) as refused:
        board_sheet(spec, paper, margin_mm)
    assert refused.value.input == input_name


def test_cli_writes_the_sheet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "board.pdf"
    assert cli.main(["target", CHECKERBOARD, "--out", str(out), "--paper", "letter", "--margin-mm", "8"]) == 0
    assert f"wrote {out}: letter landscape" in capsys.readouterr().err
    assert out.read_bytes() == board_sheet(CHECKERBOARD, "letter", 8.0).pdf


@pytest.mark.parametrize(("args", "message"), [
    (["checkerboard:9x6"], "has the wrong number of fields"),
    ([CHARUCO, "--paper", "a4"], "needs a sheet of 350 x 274 mm"),
    ([CHECKERBOARD, "--paper", "a5"], "unknown paper 'a5'"),
    ([CHECKERBOARD, "--margin-mm", "1"], "expected at least 5 mm"),
])
def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str],
                                 message: str) -> None:
    out = tmp_path / "board.pdf"
    assert cli.main(["target", *args, "--out", str(out)]) == cli.EXIT_INPUT_ERROR
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and message in lines[0], lines
    assert not out.exists()


def test_cli_refuses_an_output_it_cannot_write(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "missing" / "board.pdf"
    assert cli.main(["target", CHECKERBOARD, "--out", str(out)]) == cli.EXIT_INPUT_ERROR
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_api_serves_the_sheet(tmp_path: Path) -> None:
    with TestClient(create_app(tmp_path)) as client:
        answer = client.get("/api/targets/pdf", params={"board": CHARUCO, "paper": "a3", "margin_mm": 12})
        assert answer.status_code == 200, answer.text
        assert answer.headers["content-type"] == "application/pdf"
        assert 'filename="charuco_11x8_30mm_22mm_DICT_5X5_100.pdf"' in answer.headers["content-disposition"]
        assert answer.content == board_sheet(CHARUCO, "a3", 12.0).pdf

        for params, status, input_name in (({"board": "checkerboard:9x6"}, 422, "board"),
                                           ({"board": CHARUCO, "paper": "a4"}, 422, "paper"),
                                           ({"board": CHECKERBOARD, "paper": "a5"}, 422, "query.paper"),
                                           ({"board": CHECKERBOARD, "margin_mm": "nan"}, 422, "margin_mm"),
                                           ({}, 422, "query.board")):
            answer = client.get("/api/targets/pdf", params=params)
            assert answer.status_code == status, (params, answer.text)
            assert answer.json()["error"]["input"] == input_name, (params, answer.json())


def test_a_board_of_too_many_squares_is_refused_from_its_spec(tmp_path: Path) -> None:
    """A 2000 x 2000 board of 0.1 mm squares fits a sheet (20 cm) but would draw four million squares: the CLI and
    the API refuse it from the spec, naming the limit, and no file is written."""
    out = tmp_path / "t.pdf"
    run = cli_in_process("target", "checkerboard:2000x2000:0.0001", "--out", out)
    assert run.returncode == 2 and not out.exists()
    assert run.stderr.strip().splitlines()[-1] == (
        "error: board 'checkerboard:2000x2000:0.0001' has 4,004,001 squares, more than the 10,000 squares limit "
        "on a printable target (CALIB_MAX_TARGET_SQUARES): nothing was drawn")
    with TestClient(create_app(tmp_path)) as client:
        answer = client.get("/api/targets/pdf", params={"board": "checkerboard:200x100:0.001"})
    assert answer.status_code == 422 and answer.json()["error"]["input"] == "board"
    assert "20,301 squares" in answer.json()["error"]["message"]
    assert BoardSpec.parse("checkerboard:99x99:0.002").n_squares == 10_000  # the largest that is drawn
