"""The CMU Laser-Camera Calibration Toolbox's method, redone, to see where the VLP-16 set's reference runs come from.

The set's README (``../shared/data/vlp16_camera_checkerboard``) gives three runs of the toolbox. Its author's
repository (github.com/DavidHan008/laser2camera_calibration, commit 392e3aa) has the toolbox as it was run. It uses
the board's planes only, in two stages (Unnikrishnan & Hebert, 2005; ``lasercamcalib.m``):
1. closed form: the translation from the planes' distances, the rotation from their normals (SVD);
2. the mean squared distance of each plane's LiDAR points from the camera's board plane, planes weighted equally.

The LiDAR's plane points are picked as the toolbox picks them (``ObtainPlanePoint.m``). The user clicks a point on the
board. A RANSAC plane (500 hypotheses of 10 points within 0.2 m of the click) takes every point of the scan within
2 cm of it, and those within 1 m of the last hypothesis's sample mean are kept. The board's corners span 0.3 x 0.25 m,
so a 1 m radius also takes in the hand, arm and body holding it, and whatever else lies near the board's plane.

:func:`reproduce` keeps the points two ways, from one RANSAC: ``toolbox``, as above, and ``board``, within
:data:`BOARD_RADIUS_M` of the board's centre in the scan. Written from the toolbox's description, for tests and
benchmarks only; no solver uses it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from backend.core.transforms import invert, make_T, transform_points

CLICK_RADIUS_M = 0.2
"""The RANSAC's hypotheses are drawn from the points this near the click (the toolbox's ``min_distance``)."""
HYPOTHESES, SAMPLE_POINTS = 500, 10
INLIER_M = 0.02
"""A point of the scan within this distance (m) of a hypothesis's plane is its inlier."""
TOOLBOX_RADIUS_M = 1.0
"""The toolbox keeps the inliers within this distance (m) of the last hypothesis's sample mean."""
BOARD_RADIUS_M = 0.22
"""The ``board`` selection: the corner grid's half-diagonal (0.195 m on the set's board) and 3 cm."""
OFF_BOARD_M = 0.3
"""A kept point farther than this (m) from the board's centre is not the board's."""


@dataclass
class Reproduction:
    """One selection's two-stage result."""

    T_camera_lidar: np.ndarray
    """4x4 (m), the LiDAR's frame into the camera's optical frame."""
    points: list[int]
    """Points kept per pose."""
    off_board_share: list[float]
    """Per pose, the share of the kept points farther than :data:`OFF_BOARD_M` from the board's centre."""


def plane_of(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane of (N, 3) ``points`` (m): unit normal n and distance d >= 0 with n.x = d."""
    centroid = points.mean(axis=0)
    return _with_distance_positive(np.linalg.svd(points - centroid)[2][-1], centroid)


def board_plane(T_camera_board: np.ndarray) -> tuple[np.ndarray, float]:
    """The board's plane in the camera's frame, as :func:`plane_of` gives planes, from its 4x4 pose (m)."""
    return _with_distance_positive(T_camera_board[:3, 2], T_camera_board[:3, 3])


def _with_distance_positive(normal: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, float]:
    """The plane through ``point`` with unit ``normal`` as (n, d) with n.x = d and d >= 0 (the toolbox's sign)."""
    distance = float(normal @ point)
    return (normal, distance) if distance >= 0 else (-normal, -distance)


def ransac_plane_points(cloud: np.ndarray, click: np.ndarray,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Every point of the (N, 3) ``cloud`` within :data:`INLIER_M` of the best hypothesis's plane, and the last
    hypothesis's sample mean (from which the toolbox, not from the click, measures its radius)."""
    near = cloud[np.linalg.norm(cloud - click, axis=1) < CLICK_RADIUS_M]
    best, kept, sample_mean = -1, cloud[:0], click
    for _ in range(HYPOTHESES):
        sample = near[rng.permutation(len(near))[:SAMPLE_POINTS]]
        normal, distance = plane_of(sample)
        inliers = np.abs(cloud @ normal - distance) < INLIER_M
        if inliers.sum() > best:
            best, kept = int(inliers.sum()), cloud[inliers]
        sample_mean = sample.mean(axis=0)
    return kept, sample_mean


def board_centre(inliers: np.ndarray, click: np.ndarray) -> np.ndarray:
    """The board's centre in the scan: the mean of the inliers near the click, taken again about that mean."""
    centre = inliers[np.linalg.norm(inliers - click, axis=1) < OFF_BOARD_M].mean(axis=0)
    return inliers[np.linalg.norm(inliers - centre, axis=1) < BOARD_RADIUS_M].mean(axis=0)


def two_stages(camera_planes: list[tuple[np.ndarray, float]], lidar_points: list[np.ndarray]) -> np.ndarray:
    """T_camera_lidar (4x4, m) by the toolbox's closed form, then its equal-weighted point-to-plane refinement."""
    theta_c = np.array([normal for normal, _ in camera_planes]).T
    alpha_c = np.array([distance for _, distance in camera_planes])
    lidar_planes = [plane_of(points) for points in lidar_points]
    theta_l = np.array([normal for normal, _ in lidar_planes]).T
    alpha_l = np.array([distance for _, distance in lidar_planes])
    t_closed = np.linalg.solve(theta_c @ theta_c.T, theta_c @ (alpha_c - alpha_l))
    U, _, Vt = np.linalg.svd(theta_l @ theta_c.T)
    R_closed = Vt.T @ U.T

    def residuals(x: np.ndarray) -> np.ndarray:
        R, t = Rotation.from_rotvec(x[:3]).as_matrix(), x[3:]
        return np.concatenate([((points @ R.T + t) @ theta_c[:, i] - alpha_c[i]) / np.sqrt(len(points))
                               for i, points in enumerate(lidar_points)])

    x = least_squares(residuals, np.concatenate([Rotation.from_matrix(R_closed).as_rotvec(), t_closed])).x
    return make_T(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:])


def reproduce(camera_planes: list[tuple[np.ndarray, float]], clouds: list[np.ndarray], clicks: list[np.ndarray],
              seed: int) -> dict[str, Reproduction]:
    """The two stages on each pose's ``toolbox`` and ``board`` points, from one RANSAC per pose seeded ``seed``.

    ``clouds`` are the scans' (N, 3) points (m, the LiDAR's frame, empty returns dropped), ``clicks`` a point of
    each on the board, ``camera_planes`` the board's plane per pose in the camera's frame (:func:`board_plane`).
    """
    rng = np.random.default_rng(seed)
    found = [ransac_plane_points(cloud, click, rng) for cloud, click in zip(clouds, clicks, strict=True)]
    centres = [board_centre(inliers, click) for (inliers, _), click in zip(found, clicks, strict=True)]
    about = {"toolbox": ([sample_mean for _, sample_mean in found], TOOLBOX_RADIUS_M),
             "board": (centres, BOARD_RADIUS_M)}
    reproductions = {}
    for selection, (points_about, radius_m) in about.items():
        kept = [inliers[np.linalg.norm(inliers - point, axis=1) < radius_m]
                for (inliers, _), point in zip(found, points_about, strict=True)]
        off_board = [float(np.mean(np.linalg.norm(points - centre, axis=1) > OFF_BOARD_M))
                     for points, centre in zip(kept, centres, strict=True)]
        reproductions[selection] = Reproduction(two_stages(camera_planes, kept), [len(p) for p in kept], off_board)
    return reproductions


def scan_points(points: np.ndarray) -> np.ndarray:
    """(N, 3) float64 of a pair's (N, >=3) points, without the organised scan's empty returns (zeros)."""
    cloud = points[:, :3].astype(np.float64)
    return cloud[np.linalg.norm(cloud, axis=1) > 0.1]


def clicks_on_boards(clouds: list[np.ndarray], T_camera_boards: list[np.ndarray], grid_centre_m: np.ndarray,
                     T_camera_lidar: np.ndarray) -> list[np.ndarray]:
    """Per pose, the scan's point nearest the board's centre (``grid_centre_m`` in the board's frame) as
    ``T_camera_lidar`` places it: a user's click on the board."""
    clicks = []
    for cloud, T_camera_board in zip(clouds, T_camera_boards, strict=True):
        centre = transform_points(invert(T_camera_lidar) @ T_camera_board, grid_centre_m[None])[0]
        clicks.append(cloud[np.argmin(np.linalg.norm(cloud - centre, axis=1))])
    return clicks
