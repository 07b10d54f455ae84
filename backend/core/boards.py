"""Calibration targets: parse a board spec and give the board's 3D corner positions.

A spec is one string (``../shared/conventions.md``):

- ``checkerboard:COLSxROWS:SQUARE`` - inner corners, square side in metres;
- ``charuco:COLSxROWS:SQUARE:MARKER:DICT`` - squares, square and marker side in
  metres, and an OpenCV ArUco dictionary name;
- ``aprilgrid:COLSxROWS:TAG_SIZE:SPACING`` - Kalibr's AprilGrid: tags (tag36h11) per row and column, the tag's
  side in metres and the gap between tags as a fraction of it.

Corner positions are in the board frame: origin at the first inner corner (an AprilGrid's: the top-left tag's
top-left corner as printed), x along the columns, y along the rows (down the sheet), z = 0 on the board surface
(metres). A board that bows carries its flex (``warp_m``, mrcal's ``calobject_warp``): the corners then leave the
plane by ``z = w_x 4 xr (1 - xr) + w_y 4 yr (1 - yr)``, ``xr`` and ``yr`` the corner's place across the corners from 0
to 1, so each term is 0 at the outer corners and its value at the centre line; z points away from a camera that sees
the printed side, so a positive flex bows the centre away from it. The spec string does not carry it: the flex is
measured (:mod:`backend.calib.intrinsics.flex`), not printed.

An AprilGrid is laid out as Kalibr prints it (``kalibr_create_target_pdf``): tag 0 at the bottom left, ids rising
to the right and then upward, and a black square of the gap's side at every crossing of the gaps. Its corners are
the tags' corners, numbered row by row from the sheet's top left over the grid of ``2 COLS`` by ``2 ROWS``, so a
view of some tags gives those tags' corners (partial views count, as for ChArUco).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Literal

import cv2
import numpy as np

from backend.core.errors import InputError, shorten
from backend.core.markers import marker_cells

BoardKind = Literal["checkerboard", "charuco", "aprilgrid"]
APRILGRID_DICTIONARY = "DICT_APRILTAG_36h11"
"""The AprilGrid's tag family, as OpenCV names it (Kalibr's tag36h11)."""


def bow_z(x: np.ndarray, y: np.ndarray, warp_m: tuple[float, float], span_m: tuple[float, float]) -> np.ndarray:
    """A bowed board's z (m) at board-plane ``x`` and ``y`` (m, arrays of one shape; the result keeps their float
    type): ``w_x 4 xr (1 - xr) + w_y 4 yr (1 - yr)`` with ``xr = x / span_x``, ``yr = y / span_y``, continued beyond
    0..1 (a plate's margin bends on)."""
    (w_x, w_y), (s_x, s_y) = warp_m, span_m
    return (4.0 * w_x / s_x**2) * x * (s_x - x) + (4.0 * w_y / s_y**2) * y * (s_y - y)


@dataclass(frozen=True)
class BoardSpec:
    """A planar calibration target."""

    kind: BoardKind
    cols: int
    """Inner corners along x (checkerboard), squares along x (ChArUco) or tags along x (AprilGrid)."""
    rows: int
    """Inner corners along y (checkerboard), squares along y (ChArUco) or tags along y (AprilGrid)."""
    square_m: float
    """A square's side (m); an AprilGrid's tag side."""
    marker_m: float = 0.0
    dictionary: str = ""
    spacing: float = 0.0
    """An AprilGrid's gap between tags as a fraction of the tag's side (Kalibr's ``tagSpacing``)."""
    warp_m: tuple[float, float] = (0.0, 0.0)
    """The board's flex along x and y (m): how far the centre line stands off the plane through the outer corners
    (the module's docstring gives the shape)."""

    @classmethod
    def parse(cls, spec: str) -> BoardSpec:
        """Parse a board spec string, raising :class:`InputError` naming the bad field."""
        parts = spec.strip().split(":")
        kind, shown = parts[0], shorten(spec)
        expected = {
            "checkerboard": "checkerboard:COLSxROWS:SQUARE (e.g. checkerboard:9x6:0.025)",
            "charuco": "charuco:COLSxROWS:SQUARE:MARKER:DICT (e.g. charuco:11x8:0.03:0.022:DICT_5X5_100)",
            "aprilgrid": "aprilgrid:COLSxROWS:TAG_SIZE:SPACING (e.g. aprilgrid:6x6:0.088:0.3)",
        }
        if kind not in expected:
            raise InputError(
                f"unknown board kind {shorten(kind)} in {shown}; expected 'checkerboard', 'charuco' or 'aprilgrid'",
                "board",
            )
        if len(parts) != {"checkerboard": 3, "charuco": 5, "aprilgrid": 4}[kind]:
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
        if kind == "aprilgrid":
            return cls._aprilgrid(cols, rows, square_m, parts[3], shown)
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

    @classmethod
    def _aprilgrid(cls, cols: int, rows: int, tag_m: float, spacing_text: str, shown: str) -> BoardSpec:
        try:
            spacing = float(spacing_text)
        except ValueError:
            raise InputError(f"spacing {shorten(spacing_text)} in {shown} is not a number (the gap between tags as a "
                             "fraction of the tag's side, e.g. 0.3)", "board") from None
        if cols < 1 or rows < 1 or cols * rows < 2:
            raise InputError(f"board {shown} is too small: at least two tags", "board")
        if not 0 < tag_m < 2:
            raise InputError(f"tag size {tag_m} m in {shown} must be in metres, between 0 and 2", "board")
        if not 0.05 <= spacing <= 1:
            raise InputError(f"spacing {spacing} in {shown} must be between 0.05 and 1 of the tag's side (Kalibr's "
                             "tagSpacing, e.g. 0.3)", "board")
        if cols * rows > cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11).bytesList.shape[0]:
            raise InputError(f"board {shown} has more tags than tag36h11 holds", "board")
        return cls("aprilgrid", cols, rows, tag_m, tag_m, APRILGRID_DICTIONARY, spacing)

    def __str__(self) -> str:
        size = f"{self.cols}x{self.rows}:{self.square_m:g}"
        if self.kind == "checkerboard":
            return f"checkerboard:{size}"
        if self.kind == "aprilgrid":
            return f"aprilgrid:{size}:{self.spacing:g}"
        return f"charuco:{size}:{self.marker_m:g}:{self.dictionary}"

    @property
    def gap_m(self) -> float:
        """An AprilGrid's gap between tags (m); 0 for other boards."""
        return self.spacing * self.square_m

    @property
    def corner_grid(self) -> tuple[int, int]:
        """(columns, rows) of inner corners (an AprilGrid's: of tag corners)."""
        if self.kind == "checkerboard":
            return self.cols, self.rows
        if self.kind == "aprilgrid":
            return 2 * self.cols, 2 * self.rows
        return self.cols - 1, self.rows - 1

    @property
    def n_corners(self) -> int:
        c, r = self.corner_grid
        return c * r

    @property
    def n_squares(self) -> int:
        """Squares of the printed board, the outer ones included (a ChArUco board's white ones hold its markers;
        an AprilGrid's are its tags)."""
        return (self.cols + 1) * (self.rows + 1) if self.kind == "checkerboard" else self.cols * self.rows

    @cached_property
    def object_points(self) -> np.ndarray:
        """(N, 3) float32 inner-corner positions in the board frame (m), row-major ids, bowed by ``warp_m``."""
        return np.column_stack([self.plane_xy, self.warp_basis @ np.asarray(self.warp_m, float)]).astype(np.float32)

    @cached_property
    def plane_xy(self) -> np.ndarray:
        """(N, 2) corner positions in the board's plane (m), row-major ids, as for any target
        (:class:`~backend.core.test_field.TestField` has its own)."""
        c, r = self.corner_grid
        grid = np.mgrid[0:c, 0:r].T.reshape(-1, 2).astype(np.float64)
        if self.kind == "aprilgrid":  # a tag's two corners a side, then the gap to the next tag
            return (grid // 2) * (self.square_m + self.gap_m) + (grid % 2) * self.square_m
        return grid * self.square_m

    @property
    def warp_span_m(self) -> tuple[float, float]:
        """Board-plane x and y (m) of the last corner, where the bow's parabolas return to 0 (they are 0 at the
        origin, the first corner, too)."""
        x, y = np.maximum(self.plane_xy.max(axis=0), 1e-12)
        return float(x), float(y)

    @cached_property
    def warp_basis(self) -> np.ndarray:
        """(N, 2) each corner's z (m) per metre of flex along x and along y (:func:`bow_z`: ``4 xr (1 - xr)`` and
        ``4 yr (1 - yr)``, ``xr``, ``yr`` its place across the corners from 0 to 1; mrcal's ``calobject_warp``)."""
        x, y = self.plane_xy.T
        return np.column_stack([bow_z(x, y, (1.0, 0.0), self.warp_span_m), bow_z(x, y, (0.0, 1.0), self.warp_span_m)])

    def with_warp(self, warp_m: tuple[float, float] | np.ndarray) -> BoardSpec:
        """This board bowed by ``warp_m`` (m, along x and y) instead of its own flex."""
        return replace(self, warp_m=(float(warp_m[0]), float(warp_m[1])))

    def aprilgrid_corner_ids(self, tag_ids: np.ndarray) -> np.ndarray:
        """(N, 4) corner ids of AprilGrid tags ``tag_ids`` (N,), in OpenCV's order for a marker (top-left,
        top-right, bottom-right, bottom-left as printed)."""
        column, sheet_row = tag_ids % self.cols, self.rows - 1 - tag_ids // self.cols  # tag 0 at the bottom left
        top_left = 2 * sheet_row * (2 * self.cols) + 2 * column
        return top_left[:, None] + np.array([0, 1, 2 * self.cols + 1, 2 * self.cols])[None, :]

    @property
    def size_m(self) -> tuple[float, float]:
        """Printed size of the full board including the outer squares (m; an AprilGrid's to its outer gap
        squares)."""
        if self.kind == "checkerboard":
            return (self.cols + 1) * self.square_m, (self.rows + 1) * self.square_m
        if self.kind == "aprilgrid":
            pitch = self.square_m + self.gap_m
            return self.cols * pitch + self.gap_m, self.rows * pitch + self.gap_m
        return self.cols * self.square_m, self.rows * self.square_m

    @property
    def outer_origin_m(self) -> np.ndarray:
        """Position of the board's outer top-left corner in the board frame (m)."""
        if self.kind == "aprilgrid":
            return np.array([-self.gap_m, -self.gap_m, 0.0])
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
        if self.kind == "aprilgrid":
            return self._aprilgrid_cells()
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

    def _aprilgrid_cells(self) -> np.ndarray:
        """An AprilGrid's black cells: every tag's (border and bits) and the squares where the gaps cross."""
        pitch, gap = self.square_m + self.gap_m, self.gap_m
        cells = []
        for tag_id in range(self.cols * self.rows):
            column, sheet_row = tag_id % self.cols, self.rows - 1 - tag_id // self.cols
            cells.append(marker_cells(self.dictionary, tag_id, self.square_m,
                                      np.array([gap + column * pitch, gap + sheet_row * pitch])))
        x, y = np.meshgrid(np.arange(self.cols + 1) * pitch, np.arange(self.rows + 1) * pitch)
        cells.append(np.column_stack([x.ravel(), y.ravel(), x.ravel() + gap, y.ravel() + gap]))
        return np.concatenate(cells).astype(float)

    def render(self, px_per_square: int = 60) -> np.ndarray:
        """A printable grayscale image of the whole board, ``px_per_square`` per square (an AprilGrid's: per tag)."""
        if self.kind == "aprilgrid":
            scale = px_per_square / self.square_m
            width, height = (round(v * scale) for v in self.size_m)
            image = np.full((height, width), 255, np.uint8)
            for x0, y0, x1, y1 in np.rint(self.dark_cells_m() * scale).astype(int):
                image[y0:y1, x0:x1] = 0
            return image
        if self.kind == "charuco":
            size = (self.cols * px_per_square, self.rows * px_per_square)
            return self.charuco_board().generateImage(size, marginSize=0)
        n_x, n_y = self.cols + 1, self.rows + 1
        tiles = (np.add.outer(np.arange(n_y), np.arange(n_x)) % 2 == 0).astype(np.uint8)
        return np.kron(1 - tiles, np.ones((px_per_square, px_per_square), np.uint8)) * 255
