"""One LiDAR-on-image overlay, drawn the same way by the studio, the API and the stored results.

Composes :mod:`backend.core.projection` and :mod:`backend.core.colour_maps`: project the
cloud with ``T_camera_sensor``, colour the kept points by depth, intensity or height over a
:class:`ColourScale` that spreads the scene's values (for depth, the 2nd to 98th percentile of
the projected points' depths), paint them onto the image, optionally add the scale's legend
beneath, and tile several overlays into one mosaic so that all scenes can be judged together.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.colour_maps import (
    INTENSITY_PERCENTILES,
    SPREAD_PERCENTILES,
    colormap,
    colour_bar,
    height_colours,
    spread_range,
)
from backend.core.projection import Projection, draw_points, project_cloud

COLOUR_MODES = ("depth", "intensity", "height")
LEGEND_WIDTH_PER_HEIGHT = 32
"""A legend beneath an overlay is 1/32 of its width high (at least 40 px), so it stays legible when zoomed out."""

Scene = tuple[np.ndarray, np.ndarray, np.ndarray | None]
"""One scene to draw: (image, gray or BGR uint8; (N, 3) sensor-frame points, m; (N,) intensities or None)."""


@dataclass(frozen=True)
class OverlayStyle:
    """How an overlay is drawn."""

    colour_by: str = "depth"
    """``depth`` (TURBO over :attr:`depth_percentiles` of the projected depths), ``intensity`` (TURBO over the 1st-99th
    percentile; depth when a cloud has none) or ``height`` (TURBO over :attr:`height_range_m`, z in the rig's root
    frame; depth without the root transform)."""
    range_m: tuple[float, float] = (0.5, 40.0)
    """Range window (m, from the sensor's origin): points outside it are not drawn."""
    occlusion_px: int = 6
    """Block size (px) of the occlusion filter; 0 draws hidden points too."""
    radius_px: int = 1
    """Each point is a square of side ``2 * radius_px + 1`` (px)."""
    height_range_m: tuple[float, float] = (-0.5, 3.0)
    """Heights (m, root frame) at the two ends of the colour map in ``height`` mode."""
    depth_percentiles: tuple[float, float] = SPREAD_PERCENTILES
    """Percentiles of the projected points' depths (camera z, m) at the two ends of the colour map in ``depth`` mode."""


@dataclass(frozen=True)
class ColourScale:
    """What an overlay's colours mean: TURBO from ``lo`` (blue) to ``hi`` (red) of ``label`` (its unit in brackets)."""

    label: str
    lo: float
    hi: float

    @property
    def mode(self) -> str:
        """The colour mode drawn (one of :data:`COLOUR_MODES`)."""
        return self.label.split(" ")[0]


def drawn_mode(style: OverlayStyle, intensities: Sequence[np.ndarray | None], T_root_sensor: np.ndarray | None) -> str:
    """The mode ``style`` draws these clouds in: intensity only when every cloud has some, height only with the
    root transform, else depth."""
    if style.colour_by == "intensity" and all(i is not None and np.isfinite(i).any() for i in intensities):
        return "intensity"
    if style.colour_by == "height" and T_root_sensor is not None:
        return "height"
    return "depth"


def colour_scale(projections: Sequence[Projection], intensities: Sequence[np.ndarray | None], style: OverlayStyle,
                 T_root_sensor: np.ndarray | None = None) -> ColourScale:
    """One scale over all ``projections`` (of clouds with ``intensities``): what :func:`point_colours` colours by."""
    mode = drawn_mode(style, intensities, T_root_sensor)
    if mode == "height":
        return ColourScale("height (m)", *style.height_range_m)
    if mode == "intensity":
        values = np.concatenate([i[p.index] for p, i in zip(projections, intensities, strict=True)])
        return ColourScale("intensity", *spread_range(values, INTENSITY_PERCENTILES))
    depths = np.concatenate([p.depth_m for p in projections]) if projections else np.zeros(0)
    return ColourScale("depth (m)", *spread_range(depths, style.depth_percentiles, fallback=style.range_m))


def point_colours(projection: Projection, points_sensor: np.ndarray, intensity: np.ndarray | None,
                  scale: ColourScale, T_root_sensor: np.ndarray | None = None) -> np.ndarray:
    """(M, 3) uint8 RGB of the projected points on ``scale`` (height needs ``T_root_sensor``)."""
    if scale.mode == "intensity":
        return colormap(intensity[projection.index], scale.lo, scale.hi)
    if scale.mode == "height":
        return height_colours(points_sensor[projection.index], T_root_sensor, scale.lo, scale.hi)
    return colormap(projection.depth_m, scale.lo, scale.hi)


def render_overlays(scenes: Sequence[Scene], T_camera_sensor: np.ndarray, camera: CameraIntrinsics,
                    style: OverlayStyle = OverlayStyle(), T_root_sensor: np.ndarray | None = None
                    ) -> tuple[list[np.ndarray], list[Projection], ColourScale]:
    """Each scene's image with its points drawn on it (BGR), its projection, and the one colour scale they share."""
    projections = [project_cloud(points, T_camera_sensor, camera, range_m=style.range_m,
                                 occlusion_px=style.occlusion_px) for _, points, _ in scenes]
    scale = colour_scale(projections, [intensity for _, _, intensity in scenes], style, T_root_sensor)
    drawn = [draw_points(image, projection.uv, point_colours(projection, points, intensity, scale, T_root_sensor),
                         radius_px=style.radius_px)
             for (image, points, intensity), projection in zip(scenes, projections, strict=True)]
    return drawn, projections, scale


def render_overlay(image: np.ndarray, points_sensor: np.ndarray, intensity: np.ndarray | None,
                   T_camera_sensor: np.ndarray, camera: CameraIntrinsics, style: OverlayStyle = OverlayStyle(),
                   T_root_sensor: np.ndarray | None = None) -> tuple[np.ndarray, Projection]:
    """``image`` (gray or BGR uint8) with the (N, 3) sensor-frame points (m) drawn on it, as BGR, and the projection."""
    drawn, projections, _ = render_overlays([(image, points_sensor, intensity)], T_camera_sensor, camera, style,
                                            T_root_sensor)
    return drawn[0], projections[0]


def with_legend(image: np.ndarray, scale: ColourScale) -> np.ndarray:
    """``image`` (BGR) with ``scale``'s colour bar beneath it, as wide as the image."""
    width = image.shape[1]
    legend = colour_bar(scale.lo, scale.hi, scale.label, width, max(40, width // LEGEND_WIDTH_PER_HEIGHT))
    return np.vstack([image, legend])


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
