"""Reflectivity edges of a spinning LiDAR's scan: where the return intensity steps along a scan line.

Paint on asphalt (lane lines, crossings), a print on a board or a change of material on a
continuous surface is no geometric edge, but a camera sees it as sharply as the LiDAR's
intensity does. On a single scan of a spinning LiDAR outdoors such edges are often the most
numerous; plane intersections (:mod:`backend.calib.lidar_camera.plane_edges`) need faces that several
scan lines cross and are few there (on the OpenCalib road frame: one box corner in view).

The scan lines are told apart by elevation (every beam of a spinning LiDAR sweeps a cone of
fixed elevation) and each is ordered by azimuth. An edge lies between two neighbouring returns
of a line that are on one continuous surface (no missing return between them, nearly the same
range) where the mean intensity of the :data:`WINDOW` returns on one side is at least
:attr:`ReflectivityEdgeSettings.min_ratio` times that on the other. Its point is the midpoint of
the two returns: the true edge is anywhere between them, so on average there. Clouds without
thin scan lines (an accumulated or non-repetitive scan) give no reflectivity edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

WINDOW = 2
"""Returns averaged on each side of a candidate edge: one would let single noisy returns through."""


@dataclass
class ReflectivityEdgeSettings:
    """How to find intensity steps along scan lines. Angles in degrees."""

    line_gap_deg: float = 0.08
    """Elevation gap (deg) that separates two scan lines: below the finest ring spacing of common spinning
    LiDARs (0.17 deg in the middle of the OpenCalib frame's 64 rings)."""
    max_line_spread_deg: float = 0.05
    """A scan line spreads over at most this much elevation (deg); thicker groups are not scan lines."""
    min_line_points: int = 50
    """Fewest returns of a scan line whose edges are looked for."""
    max_azimuth_gap: float = 1.5
    """Neighbouring returns further apart in azimuth than this many of the line's median steps have a missing
    return between them: not one continuous surface."""
    max_range_step: float = 0.05
    """Neighbouring returns whose ranges differ by more than this fraction are on different surfaces."""
    min_ratio: float = 2.0
    """Least ratio of the brighter side's mean intensity to the darker side's."""
    min_step: float = 0.1
    """Least difference of the two sides' mean intensities, as a fraction of the cloud's 5-95 percentile
    intensity range (units vary between LiDARs; this keeps dark, noisy surfaces from passing the ratio)."""


def find_reflectivity_edges(points_lidar: np.ndarray, intensity: np.ndarray,
                            settings: ReflectivityEdgeSettings | None = None) -> np.ndarray:
    """(M, 3) reflectivity edge points (m, LiDAR frame) of a single scan's (N, 3) points and (N,) intensities."""
    settings = settings or ReflectivityEdgeSettings()
    points = np.asarray(points_lidar, dtype=np.float64)[:, :3]
    intensity = np.asarray(intensity, dtype=np.float64)
    lo, hi = np.percentile(intensity, [5, 95]) if len(intensity) else (0.0, 0.0)
    min_step = settings.min_step * (hi - lo)
    edges = [_line_edges(points[line], intensity[line], min_step, settings) for line in _scan_lines(points, settings)]
    return np.vstack(edges) if edges else np.zeros((0, 3))


def _scan_lines(points: np.ndarray, settings: ReflectivityEdgeSettings) -> list[np.ndarray]:
    """Indices of the returns of each scan line, ordered by azimuth."""
    elevation = np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))
    order = np.argsort(elevation)
    breaks = np.flatnonzero(np.diff(elevation[order]) > settings.line_gap_deg) + 1
    lines = []
    for members in np.split(order, breaks):
        spread = np.ptp(elevation[members]) if len(members) else 0.0
        if len(members) >= settings.min_line_points and spread <= settings.max_line_spread_deg:
            azimuth = np.arctan2(points[members, 1], points[members, 0])
            lines.append(members[np.argsort(azimuth)])
    return lines


def _line_edges(points: np.ndarray, intensity: np.ndarray, min_step: float, settings: ReflectivityEdgeSettings
                ) -> np.ndarray:
    """Edge points (K, 3) between neighbouring returns of one azimuth-ordered scan line (m)."""
    azimuth = np.unwrap(np.arctan2(points[:, 1], points[:, 0]))
    step = np.diff(azimuth)
    distance = np.linalg.norm(points, axis=1)
    # Gap i joins returns i and i + 1 on one surface.
    continuous = (step <= settings.max_azimuth_gap * np.median(step)) & (
        np.abs(np.diff(distance)) <= settings.max_range_step * np.minimum(distance[:-1], distance[1:]))
    if len(continuous) < 2 * WINDOW - 1:
        return np.zeros((0, 3))
    # Gap i is a candidate when the WINDOW returns on each side (i - WINDOW + 1 .. i + WINDOW) are all joined.
    joined = sliding_window_view(continuous, 2 * WINDOW - 1).all(axis=1)
    side = sliding_window_view(intensity, WINDOW).mean(axis=1)
    left, right = side[: len(joined)], side[WINDOW:]
    brighter, darker = np.maximum(left, right), np.minimum(left, right)
    edge = joined & (brighter - darker >= min_step) & (brighter >= settings.min_ratio * darker)
    gap = np.flatnonzero(edge) + WINDOW - 1
    # A step spread over two gaps passes on both: keep the gap with the larger jump of each run.
    jump = np.abs(np.diff(intensity))
    keep = np.ones(len(gap), bool)
    neighbours = np.flatnonzero(np.diff(gap) == 1)
    weaker = np.where(jump[gap[neighbours]] < jump[gap[neighbours + 1]], neighbours, neighbours + 1)
    keep[weaker] = False
    gap = gap[keep]
    return (points[gap] + points[gap + 1]) / 2
