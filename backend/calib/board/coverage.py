"""How well a set of board views covers what intrinsic calibration needs.

The four per-view parameters and the progress rule follow ROS
``camera_calibration`` (``calibrator.py``): X and Y of the board's centre, its
apparent size and its skew, each in [0, 1]. A new view adds coverage when its L1
distance to every kept view exceeds 0.2; a parameter's bar is full when the kept
views span its range (0.7, 0.7, 0.4, 0.5), counted from 0 for size and skew. ROS calls the data good enough at 40
views or full bars; we add a heat map of where corners have landed, since
distortion is only constrained where corners were seen.

"Enough data" is stricter than ROS's rule (:func:`enough_data`): the coverage must
be full (every bar, and :data:`FULL_CELLS` of the heat map) *and* a solve of these
views must give a worst projection sigma across the image below
:data:`~backend.core.verdict.PROJECTION_TOLERANCE_PX`. Coverage alone says where
corners landed, not whether they pin the lens down there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from backend.calib.board.detection import Detection
from backend.core.boards import BoardSpec
from backend.core.verdict import PROJECTION_TOLERANCE_PX

PARAM_NAMES = ("x", "y", "size", "skew")
PARAM_RANGES = np.array([0.7, 0.7, 0.4, 0.5])
MIN_PARAM_DISTANCE = 0.2
MIN_VIEWS_WITH_FULL_BARS = 10
HEATMAP_CELLS = (16, 9)
"""Heat map grid (columns, rows) over the image."""
FULL_CELLS = 0.95
"""Fraction of heat-map cells that must hold a corner for the coverage to be full: at most 7 of the 144 may
stay empty (the outermost cells of a wide lens are hard to reach with the whole board in view)."""


def _board_outline(detection: Detection, board: BoardSpec) -> np.ndarray:
    """(4, 2) pixels of the outermost detected corners: up-left, up-right, down-right, down-left.

    For partial (ChArUco) views this is the bounding quadrilateral of the detected
    corner ids in board coordinates (for a test field: in its best-fitting plane's).
    """
    col, row = board.plane_xy[detection.ids].T
    picks = []
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        picks.append(np.argmax(sx * col + sy * row))
    return detection.corners_px[picks]


def view_parameters(detection: Detection, board: BoardSpec) -> np.ndarray:
    """ROS's [x, y, size, skew] of one view, each in [0, 1]."""
    width, height = detection.image_size
    ul, ur, dr, dl = _board_outline(detection, board)
    d1, d2 = dr - ul, dl - ur
    area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])  # quadrilateral area from its diagonals
    border = np.sqrt(area)
    mean = detection.corners_px.mean(axis=0)
    p_x = np.clip((mean[0] - border / 2) / max(width - border, 1e-9), 0, 1)
    p_y = np.clip((mean[1] - border / 2) / max(height - border, 1e-9), 0, 1)
    p_size = np.sqrt(area / (width * height))
    u, v = ul - ur, dr - ur
    angle = np.arccos(np.clip(u @ v / (np.linalg.norm(u) * np.linalg.norm(v) + 1e-12), -1, 1))
    skew = min(1.0, 2.0 * abs(np.pi / 2 - angle))
    return np.array([p_x, p_y, p_size, skew])


@dataclass
class Coverage:
    """Running coverage of the kept views of one camera."""

    board: BoardSpec
    image_size: tuple[int, int]
    params: list[np.ndarray] = field(default_factory=list)
    heatmap: np.ndarray = field(default_factory=lambda: np.zeros(HEATMAP_CELLS[::-1], int))

    def adds_coverage(self, detection: Detection) -> bool:
        """True when a view is worth capturing: it puts corners into a heat-map cell no kept view reached, or it
        differs enough from every kept view (position, size, skew)."""
        if not self.params:
            return True
        cells = self._cells(detection)
        if np.any(self.heatmap[cells[:, 1], cells[:, 0]] == 0):
            return True
        p = view_parameters(detection, self.board)
        return float(np.min(np.abs(np.array(self.params) - p).sum(axis=1))) > MIN_PARAM_DISTANCE

    def add(self, detection: Detection) -> None:
        """Record a kept view."""
        self.params.append(view_parameters(detection, self.board))
        cells = self._cells(detection)
        np.add.at(self.heatmap, (cells[:, 1], cells[:, 0]), 1)

    def _cells(self, detection: Detection) -> np.ndarray:
        """(N, 2) heat-map cells (column, row) of the detection's corners."""
        width, height = self.image_size
        cells = np.floor(detection.corners_px / [width, height] * HEATMAP_CELLS).astype(int)
        return np.clip(cells, 0, np.array(HEATMAP_CELLS) - 1)

    @property
    def progress(self) -> dict[str, float]:
        """Per-parameter progress in [0, 1] (the coverage bars)."""
        if not self.params:
            return dict.fromkeys(PARAM_NAMES, 0.0)
        p = np.array(self.params)
        # As ROS does, size and skew count from 0: small or square boards earn nothing, only large or skewed ones.
        low = np.concatenate([p[:, :2].min(axis=0), [0.0, 0.0]])
        span = np.minimum((p.max(axis=0) - low) / PARAM_RANGES, 1.0)
        return {name: float(s) for name, s in zip(PARAM_NAMES, span, strict=True)}

    @property
    def cells_seen(self) -> float:
        """Fraction of heat-map cells with at least one corner."""
        return float(np.count_nonzero(self.heatmap) / self.heatmap.size)

    def missing(self) -> list[str]:
        """What keeps the coverage from being full (empty when it is): bars, heat-map cells, views."""
        # floored: a bar just short of full must not read 100 %
        missing = [f"{name.upper()} bar at {np.floor(100 * value):.0f}%" for name, value in self.progress.items()
                   if value < 1.0]
        if self.cells_seen < FULL_CELLS:
            missing.append(f"corners seen in {self.cells_seen:.0%} of the image ({FULL_CELLS:.0%} needed)")
        if len(self.params) < MIN_VIEWS_WITH_FULL_BARS:
            missing.append(f"{len(self.params)} views ({MIN_VIEWS_WITH_FULL_BARS} needed)")
        return missing

    @property
    def full(self) -> bool:
        """Every bar full, :data:`FULL_CELLS` of the heat map seen, at least a handful of views."""
        return not self.missing()

    def summary(self) -> dict:
        return {
            "views": len(self.params),
            "progress": self.progress,
            "cells_seen": self.cells_seen,
            "heatmap": self.heatmap.tolist(),
            "full": self.full,
        }


def enough_data(coverage: Coverage | None, projection_uncertainty: dict[str, Any] | None) -> tuple[bool, list[str]]:
    """Whether the views are enough, and what is missing (one phrase each; empty when enough).

    ``projection_uncertainty`` is a solve's (``IntrinsicsResult.projection_uncertainty``) of these same views,
    or None when there is none yet. Enough takes full coverage and a worst projection sigma across the image
    below :data:`PROJECTION_TOLERANCE_PX`; the phrase for the sigma says where it is worst.
    """
    missing = ["no views yet"] if coverage is None else coverage.missing()
    if projection_uncertainty is None:
        missing.append("solve to see the projection sigma")
    elif projection_uncertainty["max_px"] >= PROJECTION_TOLERANCE_PX:
        sigma = np.asarray(projection_uncertainty["sigma_px"])
        row, col = np.unravel_index(int(np.argmax(sigma)), sigma.shape)
        missing.append(f"{sigma[row, col]:.2f} px in the {_region(row, col, sigma.shape)}: add views there "
                       f"(below {PROJECTION_TOLERANCE_PX} px needed)")
    return not missing, missing


def _region(row: int, col: int, shape: tuple[int, int]) -> str:
    """Where a cell of a (rows, cols) grid lies: 'top left corner', 'right edge', 'centre', ..."""
    rows, cols = shape
    vertical = "top" if row < rows / 3 else "bottom" if row >= 2 * rows / 3 else ""
    horizontal = "left" if col < cols / 3 else "right" if col >= 2 * cols / 3 else ""
    if vertical and horizontal:
        return f"{vertical} {horizontal} corner"
    return f"{vertical or horizontal} edge" if vertical or horizontal else "centre"
