"""The board's corners found in a swept scanner's intensity image, drawn for a person to check them: the image
around the board, its rows stretched so that a pixel spans the same angle both ways (a servo step is several beam
spacings), the corners marked row by row. Drawn with OpenCV, like the camera's detections
(:mod:`backend.plots.board`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from backend.core.colour_maps import colormap
from backend.plots.render import PANEL_WIDTH_PX

if TYPE_CHECKING:
    from backend.calib.lidar_camera.sweep_corners import SweepCorners

MARGIN_SQUARES = 1.5
"""The view reaches this many of the board's squares beyond its outermost corners."""


def sweep_corners_view(corners: SweepCorners, columns: int, width: int = PANEL_WIDTH_PX) -> np.ndarray:
    """RGB uint8 view, ``width`` px wide, of the intensity image around the found corners, each marked with a ring
    coloured by its board row (``columns`` inner corners a row) and joined to the next in its row."""
    image = corners.image
    step_rad = float(np.median(np.abs(np.diff(image.servo_angles_rad)))) if len(image.servo_angles_rad) > 1 else 1.0
    beam_rad = float(image.scan_angles_rad[-1] - image.scan_angles_rad[0]) / max(len(image.scan_angles_rad) - 1, 1)
    stretch = max(step_rad / beam_rad, 1.0)
    square = np.array([1.0, stretch])
    pixels = corners.image_px * square  # column, row in square-angle pixels
    spacing = np.median(np.linalg.norm(np.diff(pixels, axis=0), axis=1)) if len(pixels) > 1 else 10.0
    low = np.floor(np.maximum(pixels.min(axis=0) - MARGIN_SQUARES * spacing, 0)).astype(int)
    size = np.array([image.intensity.shape[1], image.intensity.shape[0] * stretch])
    high = np.ceil(np.minimum(pixels.max(axis=0) + MARGIN_SQUARES * spacing, size)).astype(int)
    scale = width / max(high[0] - low[0], 1)
    stretched = cv2.resize(image.intensity, (int(round(size[0] * scale)), int(round(size[1] * scale))),
                           interpolation=cv2.INTER_NEAREST)
    view = cv2.cvtColor(stretched[int(low[1] * scale):int(high[1] * scale), int(low[0] * scale):int(high[0] * scale)],
                        cv2.COLOR_GRAY2RGB)
    drawn = (pixels - low + 0.5) * scale - 0.5
    rows = corners.ids // columns
    colours = colormap(rows.astype(float), 0.0, float(max(rows.max(), 1)))
    radius = max(int(round(0.15 * spacing * scale)), 3)
    for k, (point, colour) in enumerate(zip(drawn, colours, strict=True)):
        centre = tuple(int(v) for v in np.round(point * 16))
        cv2.circle(view, centre, radius * 16, tuple(int(c) for c in colour), 2, cv2.LINE_AA, shift=4)
        if k + 1 < len(drawn) and corners.ids[k + 1] == corners.ids[k] + 1 and rows[k + 1] == rows[k]:
            end = tuple(int(v) for v in np.round(drawn[k + 1] * 16))
            cv2.line(view, centre, end, tuple(int(c) for c in colour), 1, cv2.LINE_AA, shift=4)
    return view
