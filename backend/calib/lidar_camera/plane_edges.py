"""Depth-continuous edges of a LiDAR cloud: where two planes meet (after Yuan et al. 2021).

A LiDAR sees two kinds of edge. Across a depth *discontinuity* (a box in front of a wall) the
foreground swells by the beam's footprint and the edge's position depends on which beams happen
to graze it; where two planes meet at an angle (a box's corner, a wall on the floor) the edge
is the intersection line of the planes fitted to their points, whose position is as precise as
the plane fits, and a camera sees it as a change of shading. Only the second kind is used here:

1. the cloud is cut into cubic voxels (:attr:`PlaneEdgeSettings.voxel_m`);
2. in each voxel (of two grids, offset by half a voxel), planes are segmented one after the other
   by RANSAC, each refitted to its inliers by least squares; a plane needs
   :attr:`~PlaneEdgeSettings.min_plane_points` inliers spread over a width of
   :attr:`~PlaneEdgeSettings.min_plane_width_m` in both directions (the points of one scan line
   fit any plane through them);
3. every pair of a voxel's planes at 30-150 deg to each other gives an intersection line, of
   which only the stretches where *both* planes have inliers close to the line are kept (two
   planes of a voxel may meet where neither of them is, e.g. a box side and a wall behind it), and
   only when each plane lies on one side of the line (a face ends at its edge);
4. the kept stretches are sampled every :attr:`~PlaneEdgeSettings.sample_step_m` into edge
   points, each with the line's direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

RANSAC_SCORED_POINTS = 2000
"""Plane hypotheses are scored on at most this many of a voxel's points (a random subset)."""


@dataclass
class PlaneEdgeSettings:
    """How to find plane-intersection edges in a cloud. Lengths in metres, angles in degrees."""

    voxel_m: float = 1.0
    """Side of the cubic voxels planes are fitted in (m). Yuan et al. use 0.5-1 m: big enough to hold two
    faces' worth of points from a sparse LiDAR, small enough that a face is flat within it."""
    plane_threshold_m: float = 0.03
    """Largest distance of a RANSAC inlier from its plane (m): about three range-noise sigmas."""
    min_plane_points: int = 30
    """Fewest inliers of a plane."""
    min_plane_width_m: float = 0.05
    """Smallest 1-sigma spread (m) of a plane's inliers in each of its two in-plane directions. The points of
    a single scan line lie on a curve that any plane through it fits; a real face spans several lines."""
    max_planes_per_voxel: int = 4
    """Planes segmented per voxel at most."""
    ransac_iterations: int = 200
    """Hypotheses per RANSAC plane: with a third of a voxel's points on a plane, the chance that none of them
    draws three of its points is 1e-3."""
    min_angle_deg: float = 30.0
    max_angle_deg: float = 150.0
    """Two planes give an edge when the angle between their normals is within this range (deg)."""
    support_m: float = 0.08
    """A plane supports a stretch of an intersection line where it has inliers within this distance of the
    line (m). It must bridge the gap between the edge and the nearest scan line on each face; larger values
    also accept planes that end short of each other (a board's lower edge above the floor)."""
    min_one_sided: float = 0.9
    """Least fraction of a plane's supporting inliers (those beyond ``plane_threshold_m`` from the line) on
    its majority side of the line: each face of a real edge ends there, while a plane that merely crosses
    another (a wall behind a pole) has points on both sides."""
    support_bin_m: float = 0.1
    """Length of the stretches (m) along a line whose support is judged one by one."""
    sample_step_m: float = 0.02
    """Spacing of the edge points sampled along the supported stretches (m)."""
    min_line_length_m: float = 0.2
    """Shortest supported stretch of a line (m, all its stretches together) that is kept."""
    seed: int = 0
    """Seeds the RANSAC, so edges are repeatable."""


@dataclass
class PlaneEdges:
    """Edge points sampled along plane intersections, in the LiDAR frame; row ``i`` of each array is one point."""

    points: np.ndarray
    """(N, 3) edge points (m)."""
    directions: np.ndarray
    """(N, 3) unit direction of the edge line through each point."""

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class _Plane:
    normal: np.ndarray
    """(3,) unit normal."""
    offset: float
    """``normal . x + offset = 0`` on the plane (m)."""
    inliers: np.ndarray
    """(K, 3) the points (m) it was fitted to."""


def find_plane_edges(points_lidar: np.ndarray, settings: PlaneEdgeSettings | None = None) -> PlaneEdges:
    """Plane-intersection edge points of an (N, 3) cloud in the LiDAR frame (m); see the module docstring.

    Runs on two voxel grids offset by half a voxel, since an edge near a voxel's face leaves only a
    sliver of one of its planes inside that voxel; the second grid's points within
    :attr:`~PlaneEdgeSettings.sample_step_m` times two of the first grid's are dropped as duplicates.
    Empty :class:`PlaneEdges` when the cloud has none (a single plane, scattered points).
    """
    settings = settings or PlaneEdgeSettings()
    rng = np.random.default_rng(settings.seed)
    points = np.asarray(points_lidar, dtype=np.float64)[:, :3]
    segments = _grid_segments(points, 0.0, settings, rng)
    if segments:
        first = cKDTree(np.vstack([samples for samples, _ in segments]))
        for samples, direction in _grid_segments(points, 0.5, settings, rng):
            distance, _ = first.query(samples, distance_upper_bound=2 * settings.sample_step_m)
            if np.count_nonzero(np.isinf(distance)) * settings.sample_step_m >= settings.min_line_length_m:
                segments.append((samples[np.isinf(distance)], direction))
    if not segments:
        return PlaneEdges(np.zeros((0, 3)), np.zeros((0, 3)))
    lengths = [len(samples) for samples, _ in segments]
    return PlaneEdges(np.vstack([samples for samples, _ in segments]),
                      np.repeat([direction for _, direction in segments], lengths, axis=0))


def _grid_segments(points: np.ndarray, offset: float, settings: PlaneEdgeSettings, rng: np.random.Generator
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Edge samples (M, 3) and direction (3,) of each intersection line found in the voxels of the grid shifted by
    ``offset`` voxels (m, LiDAR frame)."""
    if not len(points):
        return []
    cells = np.floor(points / settings.voxel_m + offset).astype(np.int64)
    first_cell = cells.min(axis=0)
    cells -= first_cell
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]  # one int per voxel: a 1-D sort
    order = np.argsort(key, kind="stable")
    segments = []
    for voxel in np.split(order, np.flatnonzero(np.diff(key[order])) + 1):
        if len(voxel) < 2 * settings.min_plane_points:
            continue
        voxel_points = points[voxel]
        lo = (cells[voxel[0]] + first_cell - offset) * settings.voxel_m
        planes = _voxel_planes(voxel_points, settings, rng)
        for i in range(len(planes)):
            for j in range(i + 1, len(planes)):
                samples = _intersection_samples(planes[i], planes[j], lo, lo + settings.voxel_m, settings)
                if samples is not None:
                    segments.append(samples)
    return segments


def _voxel_planes(points: np.ndarray, settings: PlaneEdgeSettings, rng: np.random.Generator) -> list[_Plane]:
    """The planes segmented one after the other from one voxel's (K, 3) points (m), least-squares refitted."""
    planes: list[_Plane] = []
    remaining = points
    while len(planes) < settings.max_planes_per_voxel and len(remaining) >= settings.min_plane_points:
        chosen = _ransac_plane(remaining, settings, rng)
        if np.count_nonzero(chosen) < settings.min_plane_points:
            break
        plane = _fit_plane(remaining[chosen])
        remaining = remaining[~chosen]
        if _is_wide(plane, settings.min_plane_width_m):
            planes.append(plane)
    return [_refit_apart(plane, planes, settings) for plane in planes]


def _refit_apart(plane: _Plane, planes: list[_Plane], settings: PlaneEdgeSettings) -> _Plane:
    """``plane`` refitted to its inliers that are not also within ``plane_threshold_m`` of another of ``planes``.

    RANSAC gives the points near an edge, within the threshold of both faces, to whichever face it finds first,
    and a few centimetres of the other face's points tilt that face's fit towards it, which moves the edge by
    millimetres (1-2 mm in simulation, always the same way).
    """
    apart = np.ones(len(plane.inliers), bool)
    for other in planes:
        if other is not plane:
            apart &= np.abs(plane.inliers @ other.normal + other.offset) > settings.plane_threshold_m
    return _fit_plane(plane.inliers[apart]) if np.count_nonzero(apart) >= settings.min_plane_points else plane


def _ransac_plane(points: np.ndarray, settings: PlaneEdgeSettings, rng: np.random.Generator) -> np.ndarray:
    """(K,) inlier mask of the best of ``ransac_iterations`` planes through three random points (K, 3) (m).

    Written out (all hypotheses scored at once on at most :data:`RANSAC_SCORED_POINTS` points) rather than
    Open3D's ``segment_plane``, which runs its hypotheses in parallel threads and so finds different planes on
    every run even when seeded: a calibration should give the same answer twice.
    """
    samples = points[rng.integers(0, len(points), (settings.ransac_iterations, 3))]  # (H, 3, 3)
    normals = np.cross(samples[:, 1] - samples[:, 0], samples[:, 2] - samples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    valid = length > 1e-9  # not three collinear (or repeated) points
    normals = normals[valid] / length[valid, None]
    offsets = -np.einsum("hi,hi->h", normals, samples[valid, 0])
    # Hypotheses are scored in float32 (5x faster; 1e-7 m off at 1 m), the chosen one's inliers in float64.
    scored = points[rng.permutation(len(points))[:RANSAC_SCORED_POINTS]].astype(np.float32)
    distances = scored @ normals.T.astype(np.float32)
    distances += offsets.astype(np.float32)
    counts = np.count_nonzero(np.abs(distances, out=distances) <= settings.plane_threshold_m, axis=0)
    if not len(counts):
        return np.zeros(len(points), bool)
    best = int(np.argmax(counts))
    return np.abs(points @ normals[best] + offsets[best]) <= settings.plane_threshold_m


def _fit_plane(points: np.ndarray) -> _Plane:
    """The least-squares plane of (K, 3) points (m): the normal is the scatter's weakest direction."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[2]
    return _Plane(normal, float(-normal @ centre), points)


def _is_wide(plane: _Plane, min_width_m: float) -> bool:
    """Whether the plane's inliers spread at least ``min_width_m`` (1-sigma, m) in both in-plane directions."""
    centred = plane.inliers - plane.inliers.mean(axis=0)
    spread = np.linalg.svd(centred, compute_uv=False) / np.sqrt(len(centred))
    return bool(spread[1] >= min_width_m)


def _intersection_samples(a: _Plane, b: _Plane, lo: np.ndarray, hi: np.ndarray, settings: PlaneEdgeSettings
                          ) -> tuple[np.ndarray, np.ndarray] | None:
    """Edge points (M, 3) along the intersection of planes ``a`` and ``b`` inside the voxel ``[lo, hi)`` (m) where
    both planes support it, and the line's unit direction (3,); None if they meet at too flat or too sharp an
    angle, or support too little of the line."""
    cos_angle = float(a.normal @ b.normal)
    if not np.cos(np.radians(settings.max_angle_deg)) <= cos_angle <= np.cos(np.radians(settings.min_angle_deg)):
        return None
    direction = np.cross(a.normal, b.normal)
    direction /= np.linalg.norm(direction)
    # The point of the line nearest the voxel's centre: on both planes, and at the centre's place along the line.
    centre = (lo + hi) / 2
    origin = np.linalg.solve(np.array([a.normal, b.normal, direction]), [-a.offset, -b.offset, direction @ centre])
    supported = None
    for plane in (a, b):
        offsets = plane.inliers - origin
        along = offsets @ direction
        # Signed distance from the line within the plane: a face that ends at the edge lies on one side of it.
        across = offsets @ np.cross(plane.normal, direction)
        near = np.abs(across) <= settings.support_m
        beyond_noise = across[near & (np.abs(across) > settings.plane_threshold_m)]
        if len(beyond_noise) and max(np.mean(beyond_noise > 0), np.mean(beyond_noise < 0)) < settings.min_one_sided:
            return None
        bins = set(np.floor(along[near] / settings.support_bin_m).astype(int).tolist())
        supported = bins if supported is None else supported & bins
    if not supported:
        return None
    per_bin = max(int(round(settings.support_bin_m / settings.sample_step_m)), 1)
    along = ((np.array(sorted(supported))[:, None] + (np.arange(per_bin) + 0.5) / per_bin) * settings.support_bin_m)
    samples = origin + along.reshape(-1, 1) * direction
    samples = samples[np.all((samples >= lo) & (samples < hi), axis=1)]
    if len(samples) * settings.sample_step_m < settings.min_line_length_m:
        return None
    return samples, direction
