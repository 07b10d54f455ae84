"""Perceptual colour maps for per-point values, from OpenCV (no plotting library needed), and their legend."""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np


def colormap(values: np.ndarray, lo: float, hi: float, cmap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """(N,) values -> (N, 3) uint8 RGB through an OpenCV colour map, ``lo`` and ``hi`` at its ends.

    Values are scaled to 0..255 in float32 and truncated to the map's 256 entries.
    """
    scaled = np.array(values, dtype=np.float32).ravel()  # a copy, scaled in place below
    scaled -= float(lo)  # Python floats keep the arithmetic in float32
    scaled /= max(float(hi) - float(lo), 1e-9)
    np.clip(scaled, 0.0, 1.0, out=scaled)
    scaled *= 255.0
    if not scaled.size:
        return np.zeros((0, 3), np.uint8)
    # A user colour map in RGB order gives RGB straight away (no channel swap afterwards).
    return cv2.applyColorMap(scaled.astype(np.uint8)[:, None], _rgb_lut(cmap)).reshape(-1, 3)


@cache
def _rgb_lut(cmap: int) -> np.ndarray:
    """OpenCV colour map ``cmap`` as a (256, 1, 3) uint8 table in RGB order, for ``cv2.applyColorMap``."""
    bgr = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cmap)
    return np.ascontiguousarray(bgr[:, :, ::-1])


SPREAD_PERCENTILES = (2.0, 98.0)
"""Percentiles of a scene's values at the colour map's ends (:func:`spread_range`)."""
INTENSITY_PERCENTILES = (1.0, 99.0)
"""Intensities at the colour map's ends: percentiles, because intensity units differ between drivers."""
SPREAD_SAMPLE = 65_536
""":func:`spread_range` reads at most this many values (an even stride): percentiles to well under 1 % of the range."""


def spread_range(values: np.ndarray, percentiles: tuple[float, float] = SPREAD_PERCENTILES,
                 fallback: tuple[float, float] = (0.0, 1.0)) -> tuple[float, float]:
    """``(lo, hi)`` between the ``percentiles`` of the finite ``values``, so that a colour map spreads them.

    A fixed range paints a scene whose depths all lie in a small part of it one colour; the 2nd to 98th
    percentile spreads any scene over the whole map and leaves the few nearest and farthest points at its
    ends. ``fallback`` when there are no finite values; a range of one value is widened to ``lo + 1e-3``.
    """
    values = np.asarray(values).ravel()
    if values.size > SPREAD_SAMPLE:
        values = values[np.linspace(0, values.size - 1, SPREAD_SAMPLE).astype(np.int64)]
    values = values[np.isfinite(values)]
    if not values.size:
        return float(fallback[0]), float(fallback[1])
    lo, hi = (float(v) for v in np.percentile(values, percentiles))
    return lo, max(hi, lo + 1e-3)


def colour_bar(lo: float, hi: float, label: str, width_px: int, height_px: int = 40,
               cmap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """A legend ``width_px`` wide, as BGR uint8: ``label`` on the left, then the colour map from ``lo`` to ``hi``
    with five tick values beneath it (``height_px`` sets the text size too)."""
    scale = height_px / 40.0
    font, size, thickness = cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale, max(1, round(scale))
    canvas = np.full((height_px, width_px, 3), 255, np.uint8)
    top, bar_h, tick_h = round(4 * scale), round(14 * scale), round(4 * scale)
    cv2.putText(canvas, label, (round(6 * scale), top + bar_h), font, size, (0, 0, 0), thickness, cv2.LINE_AA)
    left = round(12 * scale) + cv2.getTextSize(label, font, size, thickness)[0][0] + round(24 * scale)
    right = width_px - round(24 * scale)
    span = max(right - left, 2)
    canvas[top:top + bar_h, left:left + span] = cv2.applyColorMap(
        np.linspace(0, 255, span).astype(np.uint8)[None, :], cmap)
    for fraction in np.linspace(0.0, 1.0, 5):
        x = left + round(fraction * (span - 1))
        cv2.line(canvas, (x, top + bar_h), (x, top + bar_h + tick_h), (0, 0, 0), thickness)
        text = f"{lo + fraction * (hi - lo):.{_decimals(hi - lo)}f}"
        text_w = cv2.getTextSize(text, font, size, thickness)[0][0]
        cv2.putText(canvas, text, (min(max(x - text_w // 2, 0), width_px - text_w), height_px - round(5 * scale)),
                    font, size, (0, 0, 0), thickness, cv2.LINE_AA)
    return canvas


def _decimals(span: float) -> int:
    """Decimals that tell a quarter of ``span`` apart: 0 for spans of 40 or more, up to 3."""
    return int(np.clip(np.ceil(-np.log10(max(span, 1e-9) / 40.0)), 0, 3))


def depth_colours(depth_m: np.ndarray, lo_m: float, hi_m: float) -> np.ndarray:
    """(M, 3) uint8 RGB of depths (m) on TURBO: ``lo_m`` blue (near), ``hi_m`` red (far)."""
    return colormap(depth_m, lo_m, hi_m)


def intensity_colours(intensity: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 RGB of return intensities on TURBO over their :data:`INTENSITY_PERCENTILES`."""
    return colormap(intensity, *spread_range(intensity, INTENSITY_PERCENTILES))


def height_colours(points_sensor: np.ndarray, T_root_sensor: np.ndarray, lo_m: float, hi_m: float) -> np.ndarray:
    """(M, 3) uint8 RGB of the points' height (z in the rig's root frame, m) on TURBO, ``lo_m`` to ``hi_m``."""
    z_root = np.asarray(points_sensor, dtype=np.float64) @ T_root_sensor[2, :3] + T_root_sensor[2, 3]
    return colormap(z_root, lo_m, hi_m)


def distance_colours(distances_m: np.ndarray, max_m: float) -> np.ndarray:
    """Cloud-to-cloud distances (m) on VIRIDIS from 0 (dark) to ``max_m`` (yellow); beyond (inf too) is red."""
    d = np.asarray(distances_m, np.float32)
    colours = colormap(np.where(np.isfinite(d), d, max_m), 0.0, max_m, cv2.COLORMAP_VIRIDIS)
    colours[~(d <= max_m)] = (230, 40, 40)
    return colours
