"""Edges of a camera image for edge-based LiDAR-camera calibration: Canny pixels, their KD-tree and distance map.

OpenCV's Canny on the Gaussian-smoothed gray image gives one-pixel-wide edge chains; chains
shorter than :attr:`ImageEdgeSettings.min_chain_px` (texture, noise) are dropped, as Yuan et al.
drop short contours. Two look-ups serve the solver: the distance transform (distance in px of
every pixel to the nearest edge pixel) scores a candidate transform in one gather, for the
coarse grid search; the KD-tree of the edge pixels gives each projected LiDAR edge point its
nearest edge pixels, to which the fine solve fits a local line. Each edge pixel is moved to the
gradient's peak across the edge (:func:`subpixel_offsets`). Pixels follow OpenCV: the centre
of the top-left pixel is (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree


@dataclass
class ImageEdgeSettings:
    """How to find edges in an image. Lengths in pixels; thresholds on 8-bit gradient magnitudes."""

    blur_sigma_px: float = 1.0
    """Sigma of the Gaussian smoothing before Canny (px)."""
    canny_low: float = 40.0
    canny_high: float = 120.0
    """Canny's hysteresis thresholds on the L2 gradient magnitude of the smoothed 8-bit image."""
    min_chain_px: int = 100
    """Edge chains (8-connected) with fewer pixels than this are dropped."""


@dataclass
class ImageEdges:
    """The edge pixels of one image."""

    pixels: np.ndarray
    """(M, 2) float64 pixel coordinates (u right, v down, px) of the edge pixels, at sub-pixel peaks."""
    distance_px: np.ndarray
    """(H, W) float32 Euclidean distance (px) of each pixel to the nearest edge pixel."""
    tree: cKDTree
    """KD-tree over ``pixels``."""

    def __len__(self) -> int:
        return len(self.pixels)


def to_gray(image: np.ndarray) -> np.ndarray:
    """The (H, W) uint8 gray image of an (H, W) gray or (H, W, 3) BGR uint8 image."""
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def subpixel_offsets(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(M, 2) offsets (du, dv) (px, within half a pixel) from the edge pixels at ``rows``, ``cols`` of the (H, W)
    image to the gradient magnitude's peak across the edge: a parabola through its values one pixel either side,
    along the gradient's direction rounded to one of the 8 neighbours.

    Canny marks the pixel on one side of a step that falls between two pixels, which would shift every edge of one
    polarity by up to half a pixel (0.03 deg at f = 900 px), alike in all pairs of a scene.
    """
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.hypot(gx, gy)
    height, width = gray.shape
    angle = np.arctan2(gy[rows, cols], gx[rows, cols])
    du, dv = np.rint(np.cos(angle)).astype(np.int64), np.rint(np.sin(angle)).astype(np.int64)
    before = magnitude[np.clip(rows - dv, 0, height - 1), np.clip(cols - du, 0, width - 1)]
    after = magnitude[np.clip(rows + dv, 0, height - 1), np.clip(cols + du, 0, width - 1)]
    centre = magnitude[rows, cols]
    curvature = before - 2 * centre + after
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(curvature < 0, 0.5 * (before - after) / curvature, 0.0)
    shift = np.clip(shift, -0.5, 0.5)
    return np.column_stack([shift * du, shift * dv])


def find_image_edges(image: np.ndarray, settings: ImageEdgeSettings | None = None) -> ImageEdges:
    """The :class:`ImageEdges` of a uint8 gray or BGR image."""
    settings = settings or ImageEdgeSettings()
    gray = to_gray(image)
    if settings.blur_sigma_px > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), settings.blur_sigma_px)
    edges = cv2.Canny(gray, settings.canny_low, settings.canny_high, L2gradient=True)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(edges, connectivity=8)
    long_chain = stats[:, cv2.CC_STAT_AREA] >= settings.min_chain_px
    long_chain[0] = False  # label 0 is the background
    edges = np.where(long_chain[labels], np.uint8(255), np.uint8(0))
    rows, cols = np.nonzero(edges)
    pixels = np.column_stack([cols, rows]) + subpixel_offsets(gray, rows, cols)
    distance = cv2.distanceTransform(np.where(edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return ImageEdges(pixels, distance, cKDTree(pixels))
