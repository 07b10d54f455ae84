"""Small diagnostic pictures for the wizard panel, drawn with OpenCV as RGB arrays.

viser's GUI shows images natively, so bar charts and heat maps are rendered here
rather than pulling in a plotting library.
"""

from __future__ import annotations

import cv2
import numpy as np

from backend.calib.board.detection import Detection, draw_detection
from backend.core.boards import BoardSpec

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


GRAPH_NODE_COLOUR = (50, 120, 220)
GRAPH_ALONE_COLOUR = (220, 60, 40)
"""A camera that shares no frame with any other: the solve cannot place it."""
CAMERA_BAR_COLOURS = [(50, 120, 220), (40, 160, 110), (150, 90, 200), (200, 140, 30), (30, 150, 170)]
FLAGGED_COLOUR = (220, 60, 40)


def _text(canvas: np.ndarray, text: str, centre: tuple[int, int], scale: float = 0.42,
          colour: tuple[int, int, int] = (0, 0, 0), background: bool = False) -> None:
    """Write ``text`` centred on ``centre`` (px), on a white box with ``background``."""
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    x = int(np.clip(centre[0] - w // 2, 2, canvas.shape[1] - w - 2))
    y = centre[1] + h // 2
    if background:
        cv2.rectangle(canvas, (x - 3, y - h - 3), (x + w + 3, y + base), (255, 255, 255), -1)
    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def observation_graph_image(cameras: list[str], frames_seen: dict[str, int], edges: list[dict],
                            reference: str | None = None, width: int = PANEL_WIDTH_PX,
                            height: int = 220) -> np.ndarray:
    """Which cameras saw the board together, how often (RGB).

    Cameras are nodes on a circle (an ellipse, to fit the panel), labelled with their name and board views; each edge
    (``{"a", "b", "frames"}``) is a line as thick as its share of the most shared frames,
    with the count written on it. The reference has a double ring; a camera in no edge is red.
    """
    canvas = np.full((height, width, 3), 255, np.uint8)
    if not cameras:
        _text(canvas, "no result yet", (width // 2, height // 2), colour=(120, 120, 120))
        return canvas
    centre, radii = np.array([width / 2, height / 2]), np.array([width * 0.32, height / 2 - 55])
    angles = np.pi + 2 * np.pi * np.arange(len(cameras)) / len(cameras)
    where = {name: tuple(int(v) for v in centre + radii * np.array([np.cos(a), np.sin(a)]))
             for name, a in zip(cameras, angles, strict=True)}
    most = max([e["frames"] for e in edges] or [1])
    for edge in edges:
        thickness = 1 + int(round(9 * edge["frames"] / most))
        cv2.line(canvas, where[edge["a"]], where[edge["b"]], (120, 120, 120), thickness, cv2.LINE_AA)
    for edge in edges:
        middle = tuple((np.array(where[edge["a"]]) + where[edge["b"]]) // 2)
        _text(canvas, str(edge["frames"]), middle, 0.5, background=True)
    linked = {name for edge in edges for name in (edge["a"], edge["b"])}
    for name, (x, y) in where.items():
        colour = GRAPH_NODE_COLOUR if name in linked else GRAPH_ALONE_COLOUR
        cv2.circle(canvas, (x, y), 16, colour, -1, cv2.LINE_AA)
        if name == reference:
            cv2.circle(canvas, (x, y), 21, colour, 2, cv2.LINE_AA)
        label_y = y + 30 if y >= centre[1] - 1 else y - 44  # below the node, or above it for the upper ones
        _text(canvas, name, (x, label_y), 0.45, colour if name not in linked else (0, 0, 0))
        _text(canvas, f"{frames_seen.get(name, 0)} views", (x, label_y + 15), 0.38, (90, 90, 90))
    cv2.putText(canvas, "shared frames per pair", (5, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    if set(cameras) - linked:
        legend = "red: no shared frame"
        (w, _), _ = cv2.getTextSize(legend, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        cv2.putText(canvas, legend, (width - w - 5, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, GRAPH_ALONE_COLOUR, 1)
    return canvas


def frame_residual_bars(cameras: list[str], frames: list[dict], width: int = PANEL_WIDTH_PX,
                        height: int = 170) -> np.ndarray:
    """Per-view reprojection RMS (px) of a multi-camera solve, one bar per camera and frame, grouped by camera
    (RGB). ``frames`` are the result's ``{"camera", "frame", "rms_px", "flagged", ...}``; flagged views (left
    out of the solve) are red with a cross above."""
    canvas = np.full((height, width, 3), 255, np.uint8)
    views = [f for camera in cameras for f in frames if f["camera"] == camera]
    if not views:
        return canvas
    top = max(max(f["rms_px"] for f in views) * 1.1, 1e-6)
    gap = 8
    left, base = 35, height - 28
    bar_w = max(1, (width - left - 5 - gap * (len(cameras) - 1)) // len(views))
    x = left
    for i, camera in enumerate(cameras):
        mine = [f for f in views if f["camera"] == camera]
        if not mine:
            continue
        start = x
        for view in mine:
            h = int((base - 22) * view["rms_px"] / top)
            colour = FLAGGED_COLOUR if view["flagged"] else CAMERA_BAR_COLOURS[i % len(CAMERA_BAR_COLOURS)]
            cv2.rectangle(canvas, (x, base - h), (x + max(bar_w - 2, 1), base), colour, -1)
            if view["flagged"]:
                _text(canvas, "x", (x + bar_w // 2, base - h - 8), 0.4, FLAGGED_COLOUR)
            x += bar_w
        _text(canvas, camera, ((start + x) // 2, base + 12), 0.38)
        x += gap
    cv2.line(canvas, (left, base), (width - 5, base), (0, 0, 0), 1)
    cv2.putText(canvas, f"{top:.2f} px", (2, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    cv2.putText(canvas, "per-frame RMS (x: flagged)", (width - 190, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                (0, 0, 0), 1)
    return canvas
