"""Kalibr's AprilGrid as a board spec: parsed with its fields checked, laid out as Kalibr prints it (tag 0 at the
bottom left, squares where the gaps cross), and its corners numbered over the grid of tag corners."""

from __future__ import annotations

import numpy as np
import pytest

from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.markers import detect_markers


def test_the_spec_round_trips_and_sizes_the_board() -> None:
    board = BoardSpec.parse("aprilgrid:6x6:0.088:0.3")
    assert str(board) == "aprilgrid:6x6:0.088:0.3" and board.corner_grid == (12, 12) and board.n_corners == 144
    assert board.size_m == pytest.approx((6 * 0.1144 + 0.0264, 6 * 0.1144 + 0.0264))
    # a tag's two corners 88 mm apart, then the 26.4 mm gap to the next tag (the spacing of Kalibr's grid)
    assert np.allclose(board.object_points[:4, 0], [0, 0.088, 0.1144, 0.2024])
    assert np.allclose(board.object_points[12:14, :2], [[0, 0.088], [0.088, 0.088]])


@pytest.mark.parametrize(("spec", "message"), [
    ("aprilgrid:6x6:0.088", "wrong number of fields; expected aprilgrid:COLSxROWS:TAG_SIZE:SPACING"),
    ("aprilgrid:6x6:0.088:wide", "spacing 'wide' in 'aprilgrid:6x6:0.088:wide' is not a number"),
    ("aprilgrid:6x6:88:0.3", "tag size 88.0 m in 'aprilgrid:6x6:88:0.3' must be in metres"),
    ("aprilgrid:6x6:0.088:3", "spacing 3.0 in 'aprilgrid:6x6:0.088:3' must be between 0.05 and 1"),
    ("aprilgrid:1x1:0.088:0.3", "too small: at least two tags"),
    ("aprilgrid:30x30:0.02:0.3", "more tags than tag36h11 holds"),
])
def test_bad_specs_are_refused_naming_the_field(spec: str, message: str) -> None:
    with pytest.raises(InputError, match=message.replace("(", r"\(")) as error:
        BoardSpec.parse(spec)
    assert error.value.input == "board"


def test_the_print_has_tag_0_at_the_bottom_left_as_kalibr_prints_it() -> None:
    board = BoardSpec.parse("aprilgrid:4x3:0.05:0.3")
    image = np.pad(board.render(80), 40, constant_values=255)
    found = detect_markers(image, board.dictionary)
    centres = {int(i): c.mean(axis=0) for i, c in zip(found.ids, found.corners_px, strict=True)}
    assert sorted(centres) == list(range(12))
    assert centres[0][0] < centres[1][0] and centres[0][1] > centres[4][1]  # ids rise rightwards, then upwards
    # a tag's corners in OpenCV's order are the board's corners its ids name, in the print's pixels
    scale = 80 / board.square_m
    ids = board.aprilgrid_corner_ids(found.ids)
    expected_px = 40 + (board.object_points[ids][..., :2] - board.outer_origin_m[:2]) * scale
    assert np.abs(found.corners_px - expected_px).max() < 1.5
    # a black square where the gaps cross, corners touching the tags' corners
    gap_px = round(board.gap_m * scale)
    assert (image[40:40 + gap_px, 40:40 + gap_px] == 0).all()
