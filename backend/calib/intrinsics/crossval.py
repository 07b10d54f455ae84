"""Cross-validation of intrinsics as mrcal does it: two calibrations from disjoint halves of the views.

Both halves see the same lens, so where the data pins the model their projections agree to within their
own uncertainties; where they disagree by more, the model cannot follow the lens (model error) or some
views are bad. For every pixel ``q`` of a grid over the image, the far point that half ``a`` sees at ``q``
is projected through half ``b``; the two calibrations' camera frames may differ by a small rotation (each
solve fixes it through its own board poses), so one rotation, fitted over the grid with each point
weighted by its expected difference, is taken out first (mrcal's ``show-projection-diff`` fits the same
implied transform). The difference is compared, point by point, with the 1-sigma expected from both
halves' projection uncertainties: ``sqrt(sigma_a^2 + sigma_b^2)``. A splined model is judged only where both
halves' boards reach: beyond them its knots are held by the regularization, whose sigma says nothing of the lens.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.camera import CameraIntrinsics
from backend.core.verdict import CROSS_CHECK_SIGMAS

CONSISTENT_FACTOR = CROSS_CHECK_SIGMAS
"""Largest difference between the halves, in expected 1-sigmas at the same pixel, that is still consistent."""


def grid_pixels(width: int, height: int, grid: tuple[int, int]) -> np.ndarray:
    """(cols * rows, 2) pixel centres (px) of a ``grid`` (columns, rows) of cells over the image, row by row."""
    cols, rows = grid
    u = (np.arange(cols) + 0.5) * width / cols
    v = (np.arange(rows) + 0.5) * height / rows
    return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)


def projection_difference(a: CameraIntrinsics, sigma_a_px: np.ndarray, b: CameraIntrinsics,
                          sigma_b_px: np.ndarray, grid: tuple[int, int],
                          judged: np.ndarray | None = None) -> dict[str, Any]:
    """Compare two calibrations of one camera over ``grid`` (columns, rows).

    ``sigma_a_px`` and ``sigma_b_px`` are each half's (rows, cols) worst-direction projection 1-sigma (px) at
    the grid's cells; ``judged`` (rows, cols) the cells compared (None: every cell; a cell where a splined model
    does not invert never is). Returns the per-cell difference (px, 0 where not judged), its ratio to the expected
    1-sigma, the worst ratio and where it is, the largest difference and where it is, and ``consistent`` (every
    ratio below :data:`CONSISTENT_FACTOR`).
    """
    pixels = grid_pixels(a.width, a.height, grid)
    expected = np.hypot(np.asarray(sigma_a_px, float), np.asarray(sigma_b_px, float)).ravel()
    rays_a, rays_b = a.rays_where_inverting(pixels), b.rays_where_inverting(pixels)
    compared = np.isfinite(rays_a[:, 0]) & np.isfinite(rays_b[:, 0])
    if judged is not None and np.any(compared & np.ravel(judged)):
        compared &= np.ravel(judged)
    rotation, _ = Rotation.align_vectors(rays_b[compared], rays_a[compared],
                                         weights=1.0 / np.maximum(expected[compared], 1e-6) ** 2)
    diff = np.zeros(len(pixels))
    diff[compared] = np.linalg.norm(b.project(rotation.apply(rays_a[compared])) - pixels[compared], axis=1)
    ratio = diff / np.maximum(expected, 1e-9)
    worst, largest = int(np.argmax(ratio)), int(np.argmax(diff))
    cols, rows = grid
    return {
        "grid": [cols, rows],
        "difference_px": np.round(diff.reshape(rows, cols), 5).tolist(),
        "expected_px": np.round(expected.reshape(rows, cols), 5).tolist(),
        "max_difference_px": float(diff[largest]),
        "max_difference_pixel": np.round(pixels[largest], 1).tolist(),
        "max_difference_ratio": float(ratio[largest]),
        "worst_ratio": float(ratio[worst]),
        "worst_pixel": np.round(pixels[worst], 1).tolist(),
        "worst_difference_px": float(diff[worst]),
        "worst_expected_px": float(expected[worst]),
        "rotation_deg": float(np.degrees(rotation.magnitude())),
        "consistent": bool(ratio[worst] < CONSISTENT_FACTOR),
    }
