"""Edges of a camera image for edge-based LiDAR-camera calibration: Canny pixels, their KD-tree and distance map.

OpenCV's Canny on the Gaussian-smoothed gray image gives one-pixel-wide edge chains; chains
shorter than :attr:`ImageEdgeSettings.min_chain_px` (texture, noise) are dropped, as Yuan et al.
drop short contours. Two look-ups serve the solver: the distance transform (distance in px of
every pixel to the nearest edge pixel) scores a candidate transform in one gather, for the
coarse grid search; the KD-tree of the edge pixels gives each projected LiDAR edge point its
nearest edge pixels, to which the fine solve fits a local line. Pixels follow OpenCV: the centre
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
    """(M, 2) float64 pixel coordinates (u right, v down, px) of the edge pixels."""
    distance_px: np.ndarray
    """(H, W) float32 Euclidean distance (px) of each pixel to the nearest edge pixel."""
    tree: cKDTree
    """KD-tree over ``pixels``."""

    def __len__(self) -> int:
        return len(self.pixels)


def to_gray(image: np.ndarray) -> np.ndarray:
    """The (H, W) uint8 gray image of an (H, W) gray or (H, W, 3) BGR uint8 image."""
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


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
    pixels = np.column_stack([cols, rows]).astype(np.float64)
    distance = cv2.distanceTransform(np.where(edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return ImageEdges(pixels, distance, cKDTree(pixels))
