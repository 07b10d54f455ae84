"""Calibration targets: parse a board spec and give the board's 3D corner positions.

A spec is one string (``../shared/conventions.md``):

- ``checkerboard:COLSxROWS:SQUARE`` - inner corners, square side in metres;
- ``charuco:COLSxROWS:SQUARE:MARKER:DICT`` - squares, square and marker side in
  metres, and an OpenCV ArUco dictionary name.

Corner positions are in the board frame: origin at the first inner corner, x along
the columns, y along the rows, z = 0 on the board surface (metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import cv2
import numpy as np

from backend.core.errors import InputError, shorten
from backend.core.markers import marker_cells

BoardKind = Literal["checkerboard", "charuco"]


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration target."""

    kind: BoardKind
    cols: int
    """Inner corners along x (checkerboard) or squares along x (ChArUco)."""
    rows: int
    """Inner corners along y (checkerboard) or squares along y (ChArUco)."""
    square_m: float
    marker_m: float = 0.0
    dictionary: str = ""

    @classmethod
    def parse(cls, spec: str) -> BoardSpec:
        """Parse a board spec string, raising :class:`InputError` naming the bad field."""
        parts = spec.strip().split(":")
        kind, shown = parts[0], shorten(spec)
        expected = {
            "checkerboard": "checkerboard:COLSxROWS:SQUARE (e.g. checkerboard:9x6:0.025)",
            "charuco": "charuco:COLSxROWS:SQUARE:MARKER:DICT (e.g. charuco:11x8:0.03:0.022:DICT_5X5_100)",
        }
        if kind not in expected:
            raise InputError(
                f"unknown board kind {shorten(kind)} in {shown}; expected 'checkerboard' or 'charuco'",
                "board",
            )
        if len(parts) != {"checkerboard": 3, "charuco": 5}[kind]:
            raise InputError(f"board spec {shown} has the wrong number of fields; expected {expected[kind]}", "board")
        try:
            cols_text, rows_text = parts[1].lower().split("x")
            cols, rows = int(cols_text), int(rows_text)
        except ValueError:
            raise InputError(f"board size {shorten(parts[1])} in {shown} is not COLSxROWS; expected {expected[kind]}",
                             "board") from None
        try:
            square_m = float(parts[2])
            marker_m = float(parts[3]) if kind == "charuco" else 0.0
        except ValueError:
            raise InputError(f"square or marker size in {shown} is not a number in metres", "board") from None
        if cols < 3 or rows < 2:
            raise InputError(f"board {shown} is too small: at least 3x2", "board")
        if not 0 < square_m < 2:
            raise InputError(f"square size {square_m} m in {shown} must be in metres, between 0 and 2", "board")
        board = cls(kind, cols, rows, square_m, marker_m, parts[4] if kind == "charuco" else "")
        if kind == "charuco":
            if not 0 < marker_m < square_m:
                raise InputError(f"marker size {marker_m} m in {shown} must be smaller than the square {square_m} m",
                                 "board")
            if not hasattr(cv2.aruco, board.dictionary) or not board.dictionary.startswith("DICT_"):
                raise InputError(f"unknown ArUco dictionary {shorten(board.dictionary)} in {shown}; e.g. DICT_5X5_100",
                                 "board")
            dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
            if dictionary.bytesList.shape[0] < (cols * rows) // 2:
                raise InputError(f"dictionary {board.dictionary} has too few markers for a {cols}x{rows} ChArUco "
                                 "board", "board")
        return board

    def __str__(self) -> str:
        size = f"{self.cols}x{self.rows}:{self.square_m:g}"
        if self.kind == "checkerboard":
            return f"checkerboard:{size}"
        return f"charuco:{size}:{self.marker_m:g}:{self.dictionary}"

    @property
    def corner_grid(self) -> tuple[int, int]:
        """(columns, rows) of inner corners."""
        if self.kind == "checkerboard":
            return self.cols, self.rows
        return self.cols - 1, self.rows - 1

    @property
    def n_corners(self) -> int:
        c, r = self.corner_grid
        return c * r

    @property
    def n_squares(self) -> int:
        """Squares of the printed board, the outer ones included (a ChArUco board's white ones hold its markers)."""
        return (self.cols + 1) * (self.rows + 1) if self.kind == "checkerboard" else self.cols * self.rows

    @cached_property
    def object_points(self) -> np.ndarray:
        """(N, 3) float32 inner-corner positions in the board frame (m), row-major ids."""
        c, r = self.corner_grid
        grid = np.mgrid[0:c, 0:r].T.reshape(-1, 2).astype(np.float32) * self.square_m
        return np.column_stack([grid, np.zeros(len(grid), np.float32)])

    @property
    def plane_xy(self) -> np.ndarray:
        """(N, 2) corner positions in the board's plane (m), as for any target (:class:`~backend.core.test_field.
        TestField` has its own)."""
        return self.object_points[:, :2]

    @property
    def size_m(self) -> tuple[float, float]:
        """Printed size of the full board including the outer squares (m)."""
        if self.kind == "checkerboard":
            return (self.cols + 1) * self.square_m, (self.rows + 1) * self.square_m
        return self.cols * self.square_m, self.rows * self.square_m

    @property
    def outer_origin_m(self) -> np.ndarray:
        """Position of the board's outer top-left corner in the board frame (m)."""
        return np.array([-self.square_m, -self.square_m, 0.0])

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV ChArUco board object (only for ``kind == 'charuco'``)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, dictionary)

    def dark_cells_m(self) -> np.ndarray:
        """(N, 4) rectangles ``[x0, y0, x1, y1]`` (m) that are black on the printed board: its black squares and, on a
        ChArUco board, each marker's black cells (border and bits). Measured from the board's outer top-left corner,
        x along the columns, y along the rows (down the sheet). ChArUco boards follow OpenCV's own layout
        (``CharucoBoard.getObjPoints``, ``Dictionary.generateImageMarker``), which :meth:`render` rasterises too."""
        n_x, n_y = round(self.size_m[0] / self.square_m), round(self.size_m[1] / self.square_m)
        if self.kind == "checkerboard":
            dark = np.add.outer(np.arange(n_y), np.arange(n_x)) % 2 == 0
            cells = []
        else:
            board = self.charuco_board()
            dark = np.ones((n_y, n_x), bool)
            cells = []
            for marker_id, corners in zip(board.getIds().ravel(), board.getObjPoints(), strict=True):
                top_left = np.asarray(corners)[0, :2]
                column, row = np.floor((top_left + self.marker_m / 2) / self.square_m).astype(int)
                dark[row, column] = False
                cells.append(marker_cells(self.dictionary, int(marker_id), self.marker_m, top_left))
        rows, cols = np.nonzero(dark)
        squares = np.column_stack([cols, rows, cols + 1, rows + 1]) * self.square_m
        return np.concatenate([squares, *cells]).astype(float)

    def render(self, px_per_square: int = 60) -> np.ndarray:
        """A printable grayscale image of the whole board, ``px_per_square`` per square."""
        if self.kind == "charuco":
            size = (self.cols * px_per_square, self.rows * px_per_square)
            return self.charuco_board().generateImage(size, marginSize=0)
        n_x, n_y = self.cols + 1, self.rows + 1
        tiles = (np.add.outer(np.arange(n_y), np.arange(n_x)) % 2 == 0).astype(np.uint8)
        return np.kron(1 - tiles, np.ones((px_per_square, px_per_square), np.uint8)) * 255
