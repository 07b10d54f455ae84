"""Coverage guidance: ROS-style bars, the heat map, auto-capture decisions and the enough-data signal."""

from __future__ import annotations

import numpy as np

from backend.calib.board.coverage import FULL_CELLS, Coverage, enough_data, view_parameters
from backend.calib.board.detection import Detection
from backend.core.boards import BoardSpec

BOARD = BoardSpec.parse("checkerboard:9x6:0.025")
SIZE = (1280, 720)


def grid_detection(centre_px: tuple[float, float], spacing_px: float, shear: float = 0.0) -> Detection:
    """A synthetic detection: the 9x6 corner grid centred at ``centre_px``, optionally sheared."""
    cols, rows = BOARD.corner_grid
    gx, gy = np.meshgrid(np.arange(cols) - (cols - 1) / 2, np.arange(rows) - (rows - 1) / 2)
    xy = np.column_stack([gx.ravel() + shear * gy.ravel(), gy.ravel()]) * spacing_px + centre_px
    return Detection(xy, np.arange(BOARD.n_corners), SIZE)


def test_view_parameters_follow_position_size_and_skew():
    def params(centre_px, spacing_px, shear=0.0):
        return view_parameters(grid_detection(centre_px, spacing_px, shear), BOARD)

    left, right = params((200, 360), 30), params((1080, 360), 30)
    assert left[0] < 0.1 and right[0] > 0.9 and abs(left[1] - 0.5) < 0.05
    assert params((640, 360), 60)[2] > 2.5 * params((640, 360), 20)[2]
    assert params((640, 360), 40)[3] < 0.01 < 0.5 < params((640, 360), 40, shear=0.4)[3]


def test_only_new_views_add_coverage_and_bars_fill():
    coverage = Coverage(BOARD, SIZE)
    first = grid_detection((640, 360), 40)
    assert coverage.adds_coverage(first)
    coverage.add(first)
    assert not coverage.adds_coverage(grid_detection((645, 362), 40))  # the same view, barely moved
    assert coverage.adds_coverage(grid_detection((250, 360), 40))
    assert coverage.progress["x"] == 0.0 and not coverage.full
    # a view like a kept one, but reaching a heat-map cell none reached (the image's corner): worth keeping
    nudged_into_the_corner = grid_detection((640, 360), 40)
    nudged_into_the_corner.corners_px[0] = (10.0, 10.0)
    assert coverage.adds_coverage(nudged_into_the_corner)

    for centre in [(200, 150), (1080, 150), (200, 570), (1080, 570)]:
        for spacing, shear in [(25, 0.0), (70, 0.0), (40, 0.45)]:
            coverage.add(grid_detection(centre, spacing, shear))
    coverage.add(grid_detection((640, 360), 120))  # close to the camera: fills the size bar
    assert all(value == 1.0 for value in coverage.progress.values()), coverage.progress
    assert coverage.heatmap.sum() == len(coverage.params) * BOARD.n_corners
    # full bars, but corners only landed in part of the image: not full (ROS would call this enough)
    assert 0.5 < coverage.cells_seen < FULL_CELLS
    assert coverage.missing() == [f"corners seen in {coverage.cells_seen:.0%} of the image (95% needed)"]
    summary = coverage.summary()
    assert summary["views"] == 14 and summary["full"] is False
    assert np.array(summary["heatmap"]).shape == (9, 16)
    for x in np.linspace(60, 1220, 12):  # sweep the board over the image's every row of cells
        for y in (40, 200, 360, 520, 680):
            coverage.add(grid_detection((x, y), 25))
    assert coverage.full and coverage.missing() == []


def test_size_and_skew_count_from_zero_as_in_ros():
    """ROS's ``compute_goodenough`` rewards large and skewed views only: its size and skew bars measure from 0."""
    near_square = Coverage(BOARD, SIZE)
    near_square.add(grid_detection((640, 360), 75))  # one near view, square to the camera
    assert near_square.progress["size"] == 1.0 and near_square.progress["skew"] < 0.05
    far_and_near = Coverage(BOARD, SIZE)
    for spacing in (20, 45):  # a far and a middling view: neither is large
        far_and_near.add(grid_detection((640, 360), spacing))
    assert 0.5 < far_and_near.progress["size"] < 1.0
    skewed = Coverage(BOARD, SIZE)
    skewed.add(grid_detection((640, 360), 40, shear=0.2))
    assert 0.5 < skewed.progress["skew"] < 1.0 and "SKEW bar at" in " ".join(skewed.missing())


def test_a_bar_short_of_full_never_reads_100_percent():
    coverage = Coverage(BOARD, SIZE)
    for x in (300, 1059):  # X spans just short of its range
        coverage.add(grid_detection((x, 360), 30))
    assert 0.99 < coverage.progress["x"] < 1.0
    assert "X bar at 99%" in coverage.missing()


def uncertainty(max_px: float, where: tuple[int, int]) -> dict:
    """A projection_uncertainty with 0.1 px everywhere but ``max_px`` at the (row, col) cell ``where``."""
    sigma = np.full((9, 16), 0.1)
    sigma[where] = max_px
    return {"sigma_px": sigma.tolist(), "max_px": max_px}


def test_enough_data_needs_full_coverage_and_a_small_projection_sigma():
    full = Coverage(BOARD, SIZE)
    for x in np.linspace(60, 1220, 12):
        for y in (40, 200, 360, 520, 680):
            for spacing, shear in [(25, 0.0), (70, 0.45)]:
                full.add(grid_detection((x, y), spacing, shear))
    full.add(grid_detection((640, 360), 120))
    assert full.full
    assert enough_data(full, None) == (False, ["solve to see the projection sigma"])
    assert enough_data(full, uncertainty(0.2, (0, 0))) == (True, [])
    enough, missing = enough_data(full, uncertainty(0.45, (0, 15)))
    assert not enough and missing == ["0.45 px in the top right corner: add views there (below 0.3 px needed)"]
    assert enough_data(full, uncertainty(0.5, (4, 8)))[1][0].startswith("0.50 px in the centre")
    partial = Coverage(BOARD, SIZE)
    partial.add(grid_detection((640, 360), 40))
    enough, missing = enough_data(partial, uncertainty(0.2, (0, 0)))
    assert not enough and "X bar at 0%" in missing and any("views (10 needed)" in m for m in missing)
    assert enough_data(None, None)[1] == ["no views yet", "solve to see the projection sigma"]
