"""Voxel grids over point clouds: one point per occupied cube, for bounded live views, streams and maps."""

from __future__ import annotations

import numpy as np


def voxel_downsample(points: np.ndarray, intensity: np.ndarray | None, voxel_m: float
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """One point per occupied ``voxel_m`` cube (the centroid of its points, and their mean intensity).

    Vectorised voxel hashing: integer voxel indices are packed into one int64 key
    (21 bits per axis, so +-1 million voxels per axis), grouped with ``np.unique``
    and averaged with ``np.bincount``.
    """
    if len(points) == 0:
        return points.reshape(0, 3), intensity
    cells = np.floor(points / voxel_m).astype(np.int64) + (1 << 20)
    keys = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    centroid = np.stack([np.bincount(inverse, weights=points[:, k]) for k in range(3)], axis=1) / counts[:, None]
    mean_intensity = None
    if intensity is not None:
        mean_intensity = (np.bincount(inverse, weights=intensity) / counts).astype(np.float32)
    return centroid, mean_intensity
