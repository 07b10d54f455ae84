"""How well a set of board views covers what intrinsic calibration needs.

The four per-view parameters and the progress rule follow ROS
``camera_calibration`` (``calibrator.py``): X and Y of the board's centre, its
apparent size and its skew, each in [0, 1]. A new view adds coverage when its L1
distance to every kept view exceeds 0.2; a parameter's bar is full when the kept
views span its range (0.7, 0.7, 0.4, 0.5). ROS calls the data good enough at 40
views or full bars; we add a heat map of where corners have landed, since
distortion is only constrained where corners were seen.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from backend.core.boards import BoardSpec
from backend.solvers.board_detection import Detection

PARAM_NAMES = ("x", "y", "size", "skew")
PARAM_RANGES = np.array([0.7, 0.7, 0.4, 0.5])
MIN_PARAM_DISTANCE = 0.2
ENOUGH_VIEWS = 40
MIN_VIEWS_WITH_FULL_BARS = 10
HEATMAP_CELLS = (16, 9)
"""Heat map grid (columns, rows) over the image."""


def _board_outline(detection: Detection, board: BoardSpec) -> np.ndarray:
    """(4, 2) pixels of the outermost detected corners: up-left, up-right, down-right, down-left.

    For partial (ChArUco) views this is the bounding quadrilateral of the detected
    corner ids in board coordinates.
    """
    cols, _ = board.corner_grid
    col, row = detection.ids % cols, detection.ids // cols
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
        """True when a view differs enough from every kept view to be worth capturing."""
        if not self.params:
            return True
        p = view_parameters(detection, self.board)
        return float(np.min(np.abs(np.array(self.params) - p).sum(axis=1))) > MIN_PARAM_DISTANCE

    def add(self, detection: Detection) -> None:
        """Record a kept view."""
        self.params.append(view_parameters(detection, self.board))
        width, height = self.image_size
        cells = np.floor(detection.corners_px / [width, height] * HEATMAP_CELLS).astype(int)
        cells = np.clip(cells, 0, np.array(HEATMAP_CELLS) - 1)
        np.add.at(self.heatmap, (cells[:, 1], cells[:, 0]), 1)

    @property
    def progress(self) -> dict[str, float]:
        """Per-parameter progress in [0, 1] (the coverage bars)."""
        if not self.params:
            return dict.fromkeys(PARAM_NAMES, 0.0)
        p = np.array(self.params)
        span = np.minimum((p.max(axis=0) - p.min(axis=0)) / PARAM_RANGES, 1.0)
        return {name: float(s) for name, s in zip(PARAM_NAMES, span, strict=True)}

    @property
    def cells_seen(self) -> float:
        """Fraction of heat-map cells with at least one corner."""
        return float(np.count_nonzero(self.heatmap) / self.heatmap.size)

    @property
    def enough(self) -> bool:
        """ROS's rule: 40 views, or every bar full with at least a handful of views."""
        full = all(v >= 1.0 for v in self.progress.values())
        return len(self.params) >= ENOUGH_VIEWS or (full and len(self.params) >= MIN_VIEWS_WITH_FULL_BARS)

    def summary(self) -> dict:
        return {
            "views": len(self.params),
            "progress": self.progress,
            "cells_seen": self.cells_seen,
            "heatmap": self.heatmap.tolist(),
            "enough": self.enough,
        }
