"""The intrinsics step's live preview: the camera frame with its captured coverage tinted and the detected
corners drawn, scaled to the panel (drawn with OpenCV on every frame; the result plots are in
:mod:`backend.plots`)."""

from __future__ import annotations

import cv2
import numpy as np

from backend.calib.board.detection import Detection, draw_detection
from backend.core.boards import BoardSpec
from backend.plots.render import PANEL_WIDTH_PX


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


def live_view(image: np.ndarray, board: BoardSpec, detection: Detection | None, heatmap: np.ndarray | None,
              width: int = PANEL_WIDTH_PX) -> np.ndarray:
    """The preview: coverage tint, then the detected corners, scaled to the panel (RGB)."""
    drawn = draw_detection(heatmap_overlay(image, heatmap), board, detection)
    scale = width / drawn.shape[1]
    small = cv2.resize(drawn, (width, int(round(drawn.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
