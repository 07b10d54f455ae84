"""Colours for point clouds in the 3D view, all vectorised, as (N, 3) uint8 RGB (or one (3,) colour).

Perceptual colour maps come from OpenCV (``cv2.applyColorMap`` on a uint8
column: TURBO for height / range / intensity, VIRIDIS for cloud-to-cloud
distance), so no plotting library is needed. The range window is applied
before anything is coloured or drawn.
"""

from __future__ import annotations

import numpy as np

from backend.core.colour_maps import colormap, height_colours, intensity_colours

COLOUR_MODES = ("sensor", "intensity", "height", "range")
SENSOR_PALETTE = ((230, 120, 30), (40, 120, 230), (200, 50, 160), (40, 170, 90), (220, 190, 30), (120, 80, 200))
"""RGB of the 1st, 2nd, ... LiDAR of the rig (by its order in the rig)."""
HEIGHT_RANGE_M = (-0.5, 3.0)
"""Height (z in the rig's root frame, m) mapped onto the colour map's ends."""
RANGE_RANGE_M = (0.0, 20.0)
"""Range from the sensor (m) mapped onto the colour map's ends."""


def range_window(points: np.ndarray, intensity: np.ndarray | None, min_m: float, max_m: float
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """Keep the points whose range from the sensor (m) lies in ``[min_m, max_m]``."""
    r2 = np.einsum("ij,ij->i", points, points)
    keep = (r2 >= min_m * min_m) & (r2 <= max_m * max_m)
    return points[keep], (intensity[keep] if intensity is not None else None)


def display_subset(points: np.ndarray, intensity: np.ndarray | None, max_points: int
                   ) -> tuple[np.ndarray, np.ndarray | None]:
    """At most ``max_points`` points for drawing: an even stride through the cloud (no copy if it fits)."""
    if len(points) <= max_points:
        return points, intensity
    index = np.linspace(0, len(points) - 1, max_points).astype(np.int64)
    return points[index], (intensity[index] if intensity is not None else None)


def padded_to_bucket(points: np.ndarray, intensity: np.ndarray | None, bucket: int
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """The cloud with its length rounded up to a multiple of ``bucket`` by repeating its first points.

    The viewer reuses a point cloud's GPU buffers in place only while its length stays the same; a
    live scan's length changes by a few points every frame, which would reallocate them every frame.
    The repeated points are drawn where they already are, so nothing changes on screen.
    """
    n = len(points)
    if n == 0 or n % bucket == 0:
        return points, intensity
    index = np.arange(-(-n // bucket) * bucket) % n
    return points[index], (intensity[index] if intensity is not None else None)


def sensor_colour(index: int) -> tuple[int, int, int]:
    return SENSOR_PALETTE[index % len(SENSOR_PALETTE)]


def colour_points(mode: str, points: np.ndarray, intensity: np.ndarray | None, T_root_sensor: np.ndarray,
                  sensor_index: int) -> np.ndarray:
    """Colours of a cloud in its sensor's frame (m) by ``mode`` (one of :data:`COLOUR_MODES`).

    ``height`` is z in the rig's root frame (``base_link``), hence ``T_root_sensor``;
    ``intensity`` spreads the 1st to 99th percentile of the cloud's own intensities
    (units differ between drivers). ``sensor``, and a cloud without intensity, give the
    sensor's one colour as a (3,) array, which viser draws for every point (a fifth of the
    bytes of a live frame need not travel).
    """
    if mode == "height":
        return height_colours(points, T_root_sensor, *HEIGHT_RANGE_M)
    if mode == "range":
        return colormap(np.sqrt(np.einsum("ij,ij->i", points, points)), *RANGE_RANGE_M)
    if mode == "intensity" and intensity is not None and len(points):
        return intensity_colours(intensity)
    return np.array(sensor_colour(sensor_index), np.uint8)
