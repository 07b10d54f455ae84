"""The board target drawn on a camera frame: the detected corners, and the intrinsics step's live preview (the
frame with its captured coverage tinted and the corners drawn, scaled to the panel). Drawn with OpenCV on every live
frame, so no matplotlib here."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from backend.calib.board.detection import normalised, to_gray
from backend.core.boards import BoardSpec
from backend.core.targets import CameraTarget
from backend.plots.render import PANEL_WIDTH_PX

if TYPE_CHECKING:
    from backend.calib.board.detection import Detection


def draw_detection(image: np.ndarray, board: CameraTarget, detection: Detection | None) -> np.ndarray:
    """BGR uint8 copy of ``image`` with the detected corners drawn (or a red 'no board' banner).

    Images deeper than 8 bits (thermal raw counts) are shown ``normalised``.
    """
    if image.dtype != np.uint8:
        image = normalised(to_gray(image))
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    if detection is None:
        cv2.putText(canvas, "board not found", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (0, 0, 255), 3)
        return canvas
    if isinstance(board, BoardSpec) and board.kind == "checkerboard":
        cv2.drawChessboardCorners(canvas, board.corner_grid, detection.corners_px.astype(np.float32).reshape(-1, 1, 2),
                                  True)
    else:  # a ChArUco board's corners, or a test field's marker centres, each with its id
        ids = detection.ids if isinstance(board, BoardSpec) else np.asarray(board.ids)[detection.ids]
        cv2.aruco.drawDetectedCornersCharuco(canvas, detection.corners_px.astype(np.float32).reshape(-1, 1, 2),
                                             ids.reshape(-1, 1).astype(np.int32))
    return canvas


def heatmap_overlay(image: np.ndarray, heatmap: np.ndarray | None) -> np.ndarray:
    """Tint the image where corners have been captured (green = seen, stronger = more often)."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    if heatmap is None or heatmap.max() == 0:
        return canvas
    cells = cv2.resize((heatmap / heatmap.max()).astype(np.float32), (canvas.shape[1], canvas.shape[0]),
                       interpolation=cv2.INTER_NEAREST)
    tint = np.zeros_like(canvas)
    tint[..., 1] = 255
    alpha = (0.35 * np.sqrt(cells))[..., None]
    return (canvas * (1 - alpha) + tint * alpha).astype(np.uint8)


def live_view(image: np.ndarray, board: CameraTarget, detection: Detection | None, heatmap: np.ndarray | None,
              width: int = PANEL_WIDTH_PX) -> np.ndarray:
    """The preview: coverage tint, then the detected corners, scaled to the panel (RGB)."""
    drawn = draw_detection(heatmap_overlay(image, heatmap), board, detection)
    scale = width / drawn.shape[1]
    small = cv2.resize(drawn, (width, int(round(drawn.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
