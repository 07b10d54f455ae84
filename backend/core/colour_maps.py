"""Perceptual colour maps for per-point values, from OpenCV (no plotting library needed)."""

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


def depth_colours(depth_m: np.ndarray, lo_m: float, hi_m: float) -> np.ndarray:
    """(M, 3) uint8 RGB of depths (m) on TURBO: ``lo_m`` blue (near), ``hi_m`` red (far)."""
    return colormap(depth_m, lo_m, hi_m)


def intensity_colours(intensity: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """(M, 3) uint8 RGB of return intensities on TURBO; the ends default to the 1st and 99th percentile.

    Percentiles, because intensity units differ between drivers.
    """
    intensity = np.asarray(intensity, dtype=np.float32).ravel()
    if (lo is None or hi is None) and intensity.size:
        p1, p99 = np.percentile(intensity, [1, 99])
        lo, hi = (float(p1) if lo is None else lo), (float(p99) if hi is None else hi)
    return colormap(intensity, lo or 0.0, hi or 1.0)


def height_colours(points_sensor: np.ndarray, T_root_sensor: np.ndarray, lo_m: float, hi_m: float) -> np.ndarray:
    """(M, 3) uint8 RGB of the points' height (z in the rig's root frame, m) on TURBO, ``lo_m`` to ``hi_m``."""
    z_root = np.asarray(points_sensor, dtype=np.float64) @ T_root_sensor[2, :3] + T_root_sensor[2, 3]
    return colormap(z_root, lo_m, hi_m)
