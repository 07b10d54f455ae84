"""Printable marker targets: a wall test field (a page per surveyed marker) and a V-target (a page per face).

The PDFs are rasterised by pdfium at a known DPI and their markers found by OpenCV: each must carry the right id, be
upright (OpenCV's corner order) and print at the spec's size and place within 0.2 mm; the test field's centre ticks
must sit outside the quiet zone on the marker's centre lines. The CLI writes both, the API serves the V-target and
refuses a test field (its survey is a file), and bad input is one line naming it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pypdfium2 as pdfium
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.errors import InputError
from backend.core.markers import detect_markers
from backend.core.test_field import survey_text
from backend.core.v_target import VTarget
from backend.exports.target_pdf import (
    CAPTION_MM,
    PAPERS_MM,
    TICK_MM,
    field_sheet,
    target_sheet,
    v_target_sheet,
)
from studio import cli
from tests.exports.test_target_pdf import DPI, MM_PER_PX, TOLERANCE_MM, scale_bar_mm

SURVEY_IDS = np.array([7, 3, 12, 0, 25, 9])
"""In survey order, which is the pages' order (not sorted)."""
VTARGET = "vtarget:0.25x0.18:90:2x2:0.06:DICT_5X5_100"
"""Faces of 250 x 180 mm: letter landscape is the first paper they and the legend fit."""


@pytest.fixture
def survey(tmp_path: Path) -> Path:
    path = tmp_path / "wall.csv"
    centres = np.column_stack([np.arange(len(SURVEY_IDS)) * 0.5, np.full(len(SURVEY_IDS), 1.2),
                               np.zeros(len(SURVEY_IDS))])
    path.write_text(survey_text(SURVEY_IDS, centres))
    return path


def pages(pdf: bytes, dpi: float = DPI) -> list[tuple[np.ndarray, tuple[float, float], str]]:
    """Every page of ``pdf``: grayscale pixels at ``dpi``, its size (mm) and its text."""
    document = pdfium.PdfDocument(pdf)
    result = []
    for page in document:
        width_pt, height_pt = page.get_size()
        pixels = page.render(scale=dpi / 72, grayscale=True).to_numpy()
        result.append(((pixels if pixels.ndim == 2 else pixels[..., 0]), (width_pt / 72 * 25.4, height_pt / 72 * 25.4),
                       page.get_textpage().get_text_range()))
    return result


def corners_mm(corners_px: np.ndarray) -> np.ndarray:
    """OpenCV's corners (px, the top-left pixel's centre at 0) as mm from the sheet's top-left corner."""
    return (corners_px + 0.5) * MM_PER_PX


def dark_runs_mm(line: np.ndarray) -> list[tuple[float, float]]:
    """The (start, end) (mm) of each run of ink along one row or column of pixels."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (line < 128).astype(np.int8), [0]])))
    return [(start * MM_PER_PX, end * MM_PER_PX) for start, end in zip(edges[::2], edges[1::2], strict=True)]


def test_a_test_field_prints_each_marker_at_exact_scale_with_its_centre_ticks(survey: Path) -> None:
    spec = f"testfield:DICT_4X4_50:0.1:{survey}"
    sheet = field_sheet(spec)
    assert b"/Subtype /Image" not in sheet.pdf, "the markers must be vector cells, not a raster"
    assert sheet.pages == len(SURVEY_IDS) and sheet.pdf.count(b"/Type /Page /") == len(SURVEY_IDS)
    assert sheet.layout.paper == "a4" and sheet.filename == "testfield_DICT_4X4_50_100mm_wall.pdf"
    side_mm, quiet_mm = 100.0, 100.0 / 6  # a 4x4 marker and its border are 6 cells a side; the quiet zone is one
    for k, (pixels, size_mm, text) in enumerate(pages(sheet.pdf)):
        np.testing.assert_allclose(size_mm, PAPERS_MM["a4"], atol=0.01)
        found = detect_markers(pixels, "DICT_4X4_50")
        assert found.ids.tolist() == [SURVEY_IDS[k]], "one marker a page, in the survey's order"
        corners = corners_mm(found.corners_px[0])
        expected = np.array([[0, 0], [1, 0], [1, 1], [0, 1]]) * side_mm + [sheet.layout.print_x_mm,
                                                                          sheet.layout.print_y_mm]
        assert np.abs(corners - expected).max() < TOLERANCE_MM, "upright, at exact scale, where the layout says"
        centre = expected.mean(axis=0)
        assert abs(sheet.layout.print_x_mm + side_mm / 2 - sheet.layout.width_mm / 2) < 1e-9, "centred across"
        column = pixels[:, int(centre[0] / MM_PER_PX)]
        row = pixels[int(centre[1] / MM_PER_PX), :]
        top, bottom = centre[1] - side_mm / 2, centre[1] + side_mm / 2
        left, right = centre[0] - side_mm / 2, centre[0] + side_mm / 2
        ticks = [run for run in dark_runs_mm(column) if run[1] < top - 1 or bottom + 1 < run[0] < bottom + 20]
        ticks += [run for run in dark_runs_mm(row) if run[1] < left - 1 or run[0] > right + 1]
        np.testing.assert_allclose(ticks, [(top - quiet_mm - TICK_MM, top - quiet_mm),
                                           (bottom + quiet_mm, bottom + quiet_mm + TICK_MM),
                                           (left - quiet_mm - TICK_MM, left - quiet_mm),
                                           (right + quiet_mm, right + quiet_mm + TICK_MM)], atol=TOLERANCE_MM)
        assert "testfield:DICT_4X4_50:0.1:wall.csv" in text and f"id {SURVEY_IDS[k]}" in text, text
        assert f"marker {SURVEY_IDS[k]} ({k + 1} of {len(SURVEY_IDS)} in the survey), 100 mm" in text, text
        assert "this bar is 100 mm" in text, text
        if k == 0:
            assert abs(scale_bar_mm(pixels) - 100.0) < TOLERANCE_MM


@pytest.mark.parametrize(("marker_m", "paper"), [(0.1, "a4"), (0.15, "a3"), (0.4, "a1")])
def test_a_test_field_takes_the_first_paper_its_marker_and_marks_fit(survey: Path, marker_m: float,
                                                                    paper: str) -> None:
    """The marker, a quiet zone of one cell (of 6 for DICT_4X4_50) and the ticks and id beyond it on every side."""
    layout = field_sheet(f"testfield:DICT_4X4_50:{marker_m}:{survey}").layout
    assert layout.paper == paper
    outer_mm = 1000 * marker_m * (1 + 2 / 6) + 2 * (TICK_MM + CAPTION_MM)
    assert min(layout.width_mm, layout.height_mm) - 2 * layout.margin_mm >= outer_mm


def test_a_v_target_prints_each_face_at_exact_scale(tmp_path: Path) -> None:
    target = VTarget.parse(VTARGET)
    sheet = v_target_sheet(VTARGET)
    assert b"/Subtype /Image" not in sheet.pdf
    assert sheet.pages == 2 and sheet.pdf.count(b"/Type /Page /") == 2
    assert sheet.filename == "vtarget_250x180mm_90deg_2x2_60mm_DICT_5X5_100.pdf"
    origin = np.array([sheet.layout.print_x_mm, sheet.layout.print_y_mm])
    half = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 1000 * target.marker_m / 2
    for face, ((pixels, size_mm, text), plate, ridge) in enumerate(zip(pages(sheet.pdf), ("left", "right"),
                                                                        ("right", "left"), strict=True)):
        np.testing.assert_allclose(size_mm, PAPERS_MM["letter"][::-1], atol=0.01)  # landscape
        found = detect_markers(pixels, target.dictionary)
        order = np.argsort(found.ids)
        assert found.ids[order].tolist() == list(range(4 * face, 4 * face + 4)), "face 0's ids, then face 1's"
        expected = origin + 1000 * target.marker_centres_print[:, None, :] + half
        assert np.abs(corners_mm(found.corners_px[order]) - expected).max() < TOLERANCE_MM
        # the hairline outline: the face's edges, 250 mm apart across the middle row
        runs = dark_runs_mm(pixels[int((origin[1] + 90.0) / MM_PER_PX), :])
        assert abs(runs[0][0] - origin[0]) < TOLERANCE_MM and abs(runs[-1][1] - origin[0] - 250.0) < TOLERANCE_MM
        assert VTARGET in text, text
        assert f"face {face}, the {plate} plate: its {ridge} edge is the ridge; 250 x 180 mm" in text, text
        legend = pixels[int(sheet.layout.legend_y_mm / MM_PER_PX):]  # the outline's edges are longer bars
        assert abs(scale_bar_mm(legend) - 100.0) < TOLERANCE_MM

    large = v_target_sheet("vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50")  # the module's example: a0, landscape
    assert (large.layout.paper, large.layout.width_mm, large.layout.height_mm, large.pages) == ("a0", 1189, 841, 2)
    sizes_mm = [np.array(page.get_size()) / 72 * 25.4 for page in pdfium.PdfDocument(large.pdf)]
    np.testing.assert_allclose(sizes_mm, [(1189.0, 841.0)] * 2, atol=0.01)


def test_prints_that_do_not_fit_are_refused_with_the_size_that_would(survey: Path) -> None:
    with pytest.raises(InputError) as too_big:
        field_sheet(f"testfield:DICT_4X4_50:1.5:{survey}")
    message = too_big.value.message
    assert too_big.value.input == "paper" and f"each marker of testfield:DICT_4X4_50:1.5:{survey}" in message
    assert "is 1500 x 1500 mm" in message and "larger than the largest paper offered, a0" in message
    largest = float(message.split("choose markers of at most ")[1].split(" mm")[0])
    assert field_sheet(f"testfield:DICT_4X4_50:{largest / 1000}:{survey}", "a0").layout.paper == "a0"

    with pytest.raises(InputError, match="larger than a4 .*: print it on a3"):
        field_sheet(f"testfield:DICT_4X4_50:0.15:{survey}", "a4")

    with pytest.raises(InputError) as too_big:
        v_target_sheet("vtarget:2x1.5:120:3x2:0.15:DICT_4X4_50")
    message = too_big.value.message
    assert "each face of vtarget:2x1.5:120:3x2:0.15:DICT_4X4_50 is 2000 x 1500 mm" in message
    assert "choose plates of at most 1076 x 807 mm for a0" in message
    assert v_target_sheet("vtarget:1.076x0.807:120:3x2:0.15:DICT_4X4_50").layout.paper == "a0"


def test_target_sheet_reads_every_kind(survey: Path) -> None:
    assert target_sheet("checkerboard:9x6:0.025").pages == 1
    assert target_sheet(f"testfield:DICT_4X4_50:0.1:{survey}").pages == len(SURVEY_IDS)
    assert target_sheet(VTARGET).pdf == v_target_sheet(VTARGET).pdf
    with pytest.raises(InputError, match="expected checkerboard, charuco, testfield or vtarget"):
        target_sheet("aprilgrid:6x6:0.1")


def test_cli_writes_a_test_field_and_a_v_target(survey: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    spec = f"testfield:DICT_APRILTAG_36h11:0.12:{survey}"
    out = tmp_path / "field.pdf"
    assert cli.main(["target", spec, "--out", str(out)]) == 0
    assert f"wrote {out}: a4 portrait, {len(SURVEY_IDS)} pages" in capsys.readouterr().err
    assert out.read_bytes() == field_sheet(spec).pdf

    out = tmp_path / "v.pdf"
    assert cli.main(["target", VTARGET, "--out", str(out), "--paper", "a3"]) == 0
    assert f"wrote {out}: a3 portrait, 2 pages" in capsys.readouterr().err
    assert out.read_bytes() == v_target_sheet(VTARGET, "a3").pdf


@pytest.mark.parametrize(("spec", "message"), [
    ("testfield:DICT_NOPE:0.1:{survey}", "unknown marker dictionary 'DICT_NOPE' in 'testfield:DICT_NOPE:0.1:"),
    ("testfield:DICT_4X4_50:0.1:{missing}", "cannot read the survey file {missing}: No such file or directory"),
    ("testfield:DICT_4X4_50:0.1:{duplicate}", "line 4: marker id 7 is surveyed twice (first on line 2)"),
    ("testfield:DICT_4X4_50:0.7:{survey}", "each marker of testfield:DICT_4X4_50:0.7:{survey} is 700 x 700 mm"),
    ("vtarget:1.0x0.6:120:3x2:0.15:DICT_NOPE", "unknown marker dictionary 'DICT_NOPE' in 'vtarget:1.0x0.6:"),
    ("vtarget:2x1.5:120:3x2:0.15:DICT_4X4_50", "is 2000 x 1500 mm; with 10 mm margins"),
])
def test_cli_bad_input_is_one_line_naming_it(survey: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             spec: str, message: str) -> None:
    duplicate = tmp_path / "twice.csv"
    duplicate.write_text("id,x,y,z\n7,0,0,0\n3,1,0,0\n7,2,0,0\n1,3,0,0\n2,4,0,0\n4,5,0,0\n")
    names = {"survey": survey, "missing": tmp_path / "missing.csv", "duplicate": duplicate}
    out = tmp_path / "target.pdf"
    assert cli.main(["target", spec.format(**names), "--out", str(out)]) == cli.EXIT_INPUT_ERROR
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and message.format(**names) in lines[0], lines
    assert not out.exists()


def test_api_serves_a_v_target_and_refuses_a_test_field(tmp_path: Path) -> None:
    with TestClient(create_app(tmp_path)) as client:
        answer = client.get("/api/targets/pdf", params={"board": VTARGET})
        assert answer.status_code == 200, answer.text
        assert answer.headers["content-type"] == "application/pdf"
        assert 'filename="vtarget_250x180mm_90deg_2x2_60mm_DICT_5X5_100.pdf"' in answer.headers["content-disposition"]
        assert answer.content == v_target_sheet(VTARGET).pdf

        # the survey is a file on the client's computer: the server refuses before reading any (this one exists)
        (tmp_path / "wall.csv").write_text("not a survey")
        answer = client.get("/api/targets/pdf", params={"board": f"testfield:DICT_4X4_50:0.15:{tmp_path}/wall.csv"})
        assert answer.status_code == 422, answer.text
        error = answer.json()["error"]
        assert error["input"] == "board" and "print test fields with the CLI (calib-studio target " in error["message"]

        for params, input_name in (({"board": "vtarget:1.0x0.6:120:3x2:0.15:DICT_NOPE"}, "board"),
                                   ({"board": "vtarget:1x0.6"}, "board"),
                                   ({"board": "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50", "paper": "a1"}, "paper"),
                                   ({"board": "nope:1"}, "board")):
            answer = client.get("/api/targets/pdf", params=params)
            assert answer.status_code == 422, (params, answer.text)
            assert answer.json()["error"]["input"] == input_name, (params, answer.json())
