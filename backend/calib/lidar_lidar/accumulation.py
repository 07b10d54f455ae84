"""Several scans of a static scene merged into one denser cloud (for one image + cloud pair).

A single spinning-LiDAR scan leaves gaps between its rings; a sensor standing still scans the same scene again
with the same rings, and a moving one (or one whose scans jitter) fills the gaps. The scans are stacked in the
first scan's frame, after registering each to the first with small_gicp's GICP when they are not already in one
frame (a LiDAR that moved between captures). Intensities are kept where every scan has them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from backend.core.clouds import check_cloud
from backend.core.errors import InputError
from backend.core.transforms import transform_points

REGISTRATION_VOXEL_M = 0.1
"""small_gicp's downsampling resolution (m) when registering the scans."""
MIN_FITNESS = 0.5
"""A registered scan must have at least this share of its downsampled points within the correspondence distance."""


def accumulate_scans(scans: Sequence[np.ndarray], *, register: bool = False, names: Sequence[str] | None = None,
                     max_correspondence_m: float = 1.0) -> np.ndarray:
    """One (M, 3) cloud, or (M, 4) with intensity as the 4th column when every scan has one, from (N_i, 3 | 4) scans
    (m) of a static scene, in the first scan's frame.

    With ``register``, every later scan is aligned to the first by GICP (small_gicp, identity start: the scans must
    overlap, as captures of a sensor at rest or moving slowly do); a scan that does not align (fewer than
    :data:`MIN_FITNESS` of its points within ``max_correspondence_m``) raises :class:`InputError` naming it
    (``names``: how errors name the scans).
    """
    if not scans:
        raise InputError("no scans to accumulate; at least one is needed", "cloud")
    names = list(names) if names is not None else [f"scan {i + 1}" for i in range(len(scans))]
    arrays = []
    for scan, name in zip(scans, names, strict=True):
        raw = np.asarray(scan, dtype=float)
        points, _ = check_cloud(raw, name)
        finite = np.isfinite(raw[:, :3]).all(axis=1)
        arrays.append(np.column_stack([points, raw[finite, 3]]) if raw.shape[1] > 3 else points)
    with_intensity = all(a.shape[1] > 3 for a in arrays)
    merged = [arrays[0] if with_intensity else arrays[0][:, :3]]
    if register and len(arrays) > 1:
        import small_gicp  # imported here: only this step needs it

        for array, name in zip(arrays[1:], names[1:], strict=True):
            result = small_gicp.align(arrays[0][:, :3], array[:, :3], downsampling_resolution=REGISTRATION_VOXEL_M,
                                      max_correspondence_distance=max_correspondence_m, num_threads=2)
            fitness = result.num_inliers / max(_downsampled(array[:, :3]), 1)
            if not result.converged or fitness < MIN_FITNESS:
                state = "converged" if result.converged else "did not converge"
                raise InputError(f"the scan does not align with {names[0]} (GICP {state}, {100 * fitness:.0f} % of "
                                 f"its points matched, at least {100 * MIN_FITNESS:.0f} % needed): is the scene "
                                 "static and do the scans overlap?", name)
            moved = transform_points(result.T_target_source, array[:, :3])
            merged.append(np.column_stack([moved, array[:, 3]]) if with_intensity else moved)
    else:
        merged += [a if with_intensity else a[:, :3] for a in arrays[1:]]
    return np.vstack(merged)


def _downsampled(points: np.ndarray) -> int:
    """How many voxels of :data:`REGISTRATION_VOXEL_M` the (N, 3) points (m) occupy: small_gicp's source size."""
    return len(np.unique(np.floor(points / REGISTRATION_VOXEL_M).astype(np.int64), axis=0))
