"""Small diagnostic pictures for the wizard panel, drawn with OpenCV as RGB arrays.

viser's GUI shows images natively, so bar charts and heat maps are rendered here
rather than pulling in a plotting library.
"""

from __future__ import annotations

import cv2
import numpy as np

from backend.core.boards import BoardSpec
from backend.solvers.board_detection import Detection, draw_detection

PANEL_WIDTH_PX = 480


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


def view_rms_bars(names: list[str], rms_px: list[float], used: list[bool], width: int = PANEL_WIDTH_PX,
                  height: int = 160) -> np.ndarray:
    """Per-view reprojection RMS as bars (px); excluded views grey, outliers red (RGB)."""
    canvas = np.full((height, width, 3), 255, np.uint8)
    if not rms_px:
        return canvas
    top = max(max(rms_px) * 1.1, 1e-6)
    median = float(np.median([r for r, u in zip(rms_px, used, strict=True) if u] or rms_px))
    bar_w = max(1, (width - 40) // len(rms_px))
    for i, (rms, is_used) in enumerate(zip(rms_px, used, strict=True)):
        h = int((height - 30) * rms / top)
        colour = (170, 170, 170) if not is_used else ((220, 60, 40) if rms > 3 * median else (50, 120, 220))
        x0 = 35 + i * bar_w
        cv2.rectangle(canvas, (x0, height - 15 - h), (x0 + max(bar_w - 2, 1), height - 15), colour, -1)
    cv2.line(canvas, (35, height - 15), (width - 5, height - 15), (0, 0, 0), 1)
    cv2.putText(canvas, f"{top:.2f} px", (2, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    cv2.putText(canvas, "per-view RMS", (width - 110, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    return canvas


def uncertainty_map(sigma_px: list[list[float]], width: int = PANEL_WIDTH_PX) -> np.ndarray:
    """Projection uncertainty across the image as a colour map with the values written in (RGB)."""
    grid = np.asarray(sigma_px, float)
    rows, cols = grid.shape
    height = int(width * 9 / 16)
    norm = np.clip(grid / max(grid.max(), 1e-9), 0, 1)
    colour = cv2.applyColorMap((norm * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    big = cv2.resize(colour, (width, height), interpolation=cv2.INTER_NEAREST)
    cell_w, cell_h = width / cols, height / rows
    for r in range(0, rows, 2):
        for c in range(0, cols, 2):
            cv2.putText(big, f"{grid[r, c]:.2f}", (int(c * cell_w + 2), int(r * cell_h + cell_h * 0.7)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.3, (255, 255, 255), 1)
    return cv2.cvtColor(big, cv2.COLOR_BGR2RGB)
