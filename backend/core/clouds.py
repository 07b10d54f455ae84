"""Checks every point cloud passes before a solver uses it: shape, finiteness, size, and units."""

from __future__ import annotations

from typing import Any

import numpy as np

from backend.core.errors import InputError

MIN_POINTS = 50
"""Fewest finite points a cloud needs before registration makes sense."""
MAX_EXTENT_M = 1000.0
"""A cloud wider than this (m, 1st-99th percentile per axis) or with a larger median range
from the sensor looks like millimetres, not metres."""

def check_cloud(points: Any, name: str) -> tuple[np.ndarray, int]:
    """Finite (N, 3) float64 points (m) of a cloud and how many non-finite rows were dropped.

    Raises :class:`InputError` naming ``name`` for a wrong shape, an empty cloud, a cloud
    with no finite point, too few points, or one whose extent looks like millimetres.
    """
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise InputError(f"expected an (N, 3) array of points in metres, got shape {arr.shape}", name)
    arr = arr[:, :3]
    if len(arr) == 0:
        raise InputError("the cloud is empty (0 points)", name)
    finite = np.isfinite(arr).all(axis=1)
    if not finite.any():
        raise InputError(f"none of the {len(arr)} points is finite (all NaN or inf)", name)
    dropped = int(len(arr) - np.count_nonzero(finite))
    arr = np.ascontiguousarray(arr[finite])
    if len(arr) < MIN_POINTS:
        raise InputError(f"only {len(arr)} finite points; at least {MIN_POINTS} are needed", name)
    lo, hi = np.percentile(arr, [1, 99], axis=0)
    extent = float(np.max(hi - lo))
    median_range = float(np.median(np.linalg.norm(arr, axis=1)))
    if extent > MAX_EXTENT_M or median_range > MAX_EXTENT_M:
        raise InputError(f"the cloud looks like millimetres, not metres (it spans {extent:.0f} units, median range "
                         f"{median_range:.0f}); points must be in metres in the sensor frame: scale by 0.001", name)
    return arr, dropped
