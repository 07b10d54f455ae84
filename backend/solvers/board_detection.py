"""Find a calibration board in an image.

Checkerboards use OpenCV's sector-based detector (``findChessboardCornersSB``),
which is sub-pixel accurate on its own; ChArUco boards use ``CharucoDetector`` so
partial views give usable corners. Corner ``ids`` index the rows of
:attr:`BoardSpec.object_points`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.boards import BoardSpec

MIN_CHARUCO_CORNERS = 6
"""Fewest ChArUco corners for a partial view to be worth keeping (PnP needs >= 4 non-collinear)."""


@dataclass
class Detection:
    """Board corners found in one image."""

    corners_px: np.ndarray
    """(N, 2) float64 corner positions in pixels (OpenCV convention)."""
    ids: np.ndarray
    """(N,) int corner ids, rows of ``board.object_points``."""
    image_size: tuple[int, int]
    """(width, height) of the image the corners were found in (px)."""

    def object_points(self, board: BoardSpec) -> np.ndarray:
        """(N, 3) float32 board-frame positions (m) of the detected corners."""
        return board.object_points[self.ids]

    def to_dict(self) -> dict:
        return {"corners_px": self.corners_px.tolist(), "ids": self.ids.tolist(), "image_size": list(self.image_size)}

    @classmethod
    def from_dict(cls, data: dict) -> Detection:
        return cls(np.asarray(data["corners_px"], float).reshape(-1, 2), np.asarray(data["ids"], int),
                   tuple(data["image_size"]))


def to_gray(image: np.ndarray) -> np.ndarray:
    """8-bit single-channel view of a gray or BGR image."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def detect_board(image: np.ndarray, board: BoardSpec, *, live: bool = False) -> Detection | None:
    """Detect ``board`` in ``image`` (gray or BGR uint8); ``None`` if it is not seen.

    ``live=True`` trades a little accuracy for speed, for preview frames; captures
    are always re-detected at full accuracy.
    """
    gray = to_gray(image)
    size = (gray.shape[1], gray.shape[0])
    if board.kind == "checkerboard":
        flags = cv2.CALIB_CB_NORMALIZE_IMAGE | (0 if live else cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        found, corners = cv2.findChessboardCornersSB(gray, board.corner_grid, flags=flags)
        if not found:
            return None
        return Detection(corners.reshape(-1, 2).astype(np.float64), np.arange(board.n_corners), size)
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    return Detection(corners.reshape(-1, 2).astype(np.float64), ids.ravel().astype(int), size)


def draw_detection(image: np.ndarray, board: BoardSpec, detection: Detection | None) -> np.ndarray:
    """BGR copy of ``image`` with the detected corners drawn (or a red 'no board' banner)."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    if detection is None:
        cv2.putText(canvas, "board not found", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (0, 0, 255), 3)
        return canvas
    if board.kind == "checkerboard":
        cv2.drawChessboardCorners(canvas, board.corner_grid, detection.corners_px.astype(np.float32).reshape(-1, 1, 2),
                                  True)
    else:
        cv2.aruco.drawDetectedCornersCharuco(canvas, detection.corners_px.astype(np.float32).reshape(-1, 1, 2),
                                             detection.ids.reshape(-1, 1))
    return canvas
