"""One LiDAR-on-image overlay, drawn the same way by the studio, the API and the stored results.

Composes :mod:`backend.core.projection` and :mod:`backend.core.colour_maps`: project the
cloud with ``T_camera_sensor``, colour the kept points by depth, intensity or height, paint
them onto the image, and optionally tile several overlays into one mosaic so that all
scenes can be judged together.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.colour_maps import depth_colours, height_colours, intensity_colours
from backend.core.projection import Projection, draw_points, project_cloud

COLOUR_MODES = ("depth", "intensity", "height")


@dataclass(frozen=True)
class OverlayStyle:
    """How an overlay is drawn."""

    colour_by: str = "depth"
    """``depth`` (TURBO over :attr:`range_m`), ``intensity`` (TURBO over the 1st-99th percentile; depth when the
    cloud has none) or ``height`` (TURBO over :attr:`height_range_m`, z in the rig's root frame)."""
    range_m: tuple[float, float] = (0.5, 40.0)
    """Range window (m, from the sensor's origin): points outside it are not drawn."""
    occlusion_px: int = 6
    """Block size (px) of the occlusion filter; 0 draws hidden points too."""
    radius_px: int = 1
    """Each point is a square of side ``2 * radius_px + 1`` (px)."""
    height_range_m: tuple[float, float] = (-0.5, 3.0)
    """Heights (m, root frame) at the two ends of the colour map in ``height`` mode."""


def point_colours(projection: Projection, points_sensor: np.ndarray, intensity: np.ndarray | None,
                  style: OverlayStyle, T_root_sensor: np.ndarray | None = None) -> np.ndarray:
    """(M, 3) uint8 RGB of the projected points in ``style.colour_by`` (height needs ``T_root_sensor``)."""
    if style.colour_by == "intensity" and intensity is not None and np.isfinite(intensity).any():
        return intensity_colours(intensity[projection.index])
    if style.colour_by == "height" and T_root_sensor is not None:
        return height_colours(points_sensor[projection.index], T_root_sensor, *style.height_range_m)
    return depth_colours(projection.depth_m, *style.range_m)


def render_overlay(image: np.ndarray, points_sensor: np.ndarray, intensity: np.ndarray | None,
                   T_camera_sensor: np.ndarray, camera: CameraIntrinsics, style: OverlayStyle = OverlayStyle(),
                   T_root_sensor: np.ndarray | None = None) -> tuple[np.ndarray, Projection]:
    """``image`` (gray or BGR uint8) with the (N, 3) sensor-frame points (m) drawn on it, as BGR, and the projection."""
    projection = project_cloud(points_sensor, T_camera_sensor, camera, range_m=style.range_m,
                               occlusion_px=style.occlusion_px)
    colours = point_colours(projection, points_sensor, intensity, style, T_root_sensor)
    return draw_points(image, projection.uv, colours, radius_px=style.radius_px), projection


def mosaic(images: Sequence[np.ndarray], width_px: int, columns: int | None = None) -> np.ndarray:
    """BGR images tiled row by row (``columns`` default: 1 for one image, else 2) into one ``width_px`` wide image.

    Each tile keeps its image's aspect ratio (tiles are sized by the first image); gaps are dark grey.
    """
    columns = columns or (1 if len(images) == 1 else 2)
    rows = -(-len(images) // columns)
    tile_w = width_px // columns
    tile_h = round(images[0].shape[0] * tile_w / images[0].shape[1])
    canvas = np.full((rows * tile_h, columns * tile_w, 3), 40, np.uint8)
    for i, image in enumerate(images):
        bgr = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image
        row, col = divmod(i, columns)
        canvas[row * tile_h:(row + 1) * tile_h, col * tile_w:(col + 1) * tile_w] = cv2.resize(
            bgr, (tile_w, tile_h), interpolation=cv2.INTER_AREA)
    return canvas
