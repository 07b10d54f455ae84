"""The fine stage of edge-based LiDAR-camera calibration: point-to-line least squares in pixels.

Each LiDAR edge point projected by the current ``T_camera_lidar`` is matched to the line through
its :attr:`FineAlignmentSettings.neighbours` nearest image edge pixels (their mean and principal
direction, as Yuan et al. 2021 do), if they are all within the round's match radius, lie
close to one line, and (for an edge whose 3D direction is known) run the way the projected edge
runs. The residual is the signed distance (px) of the projected point from its line; robust least
squares (:func:`scipy.optimize.least_squares`) solves for the six parameters about the round's
start, jointly over all pairs, and the caller re-matches and solves again with a smaller radius.

Parameters follow :func:`backend.calib.lidar_lidar.gicp.params_between`: translation (m, camera axes)
and a right-perturbation rotation vector (rad, about the LiDAR's axes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import OptimizeResult, least_squares

from backend.calib.lidar_camera.image_edges import ImageEdges
from backend.core.camera import CameraIntrinsics
from backend.core.projection import project_cloud
from backend.core.transforms import apply_params, right_jacobian, transform_points


@dataclass
class FineAlignmentSettings:
    """How to match and solve. Lengths in pixels unless named otherwise."""

    match_radius_px: tuple[float, ...] = (20.0, 12.0, 8.0, 5.0, 3.0)
    """Largest distance (px) from a projected LiDAR edge point to its nearest image edge pixels, per round; the
    last applies to all later rounds. Wide at first, so edges the coarse search left a few pixels off still
    pull; tight at the end, so that neighbouring image edges are not mistaken for one's own."""
    max_rounds: int = 10
    """Match + solve rounds at most."""
    step_tolerance: tuple[float, float] = (1e-4, 0.002)
    """After the last radius is reached, the rounds stop when one moves the estimate less than this (m, deg)."""
    neighbours: int = 5
    """Image edge pixels a local image line is fitted to (Yuan et al.: 5)."""
    max_line_rms_px: float = 1.0
    """Largest rms distance (px) of those pixels from their line: more is a corner or clutter, not one edge."""
    max_direction_angle_deg: float = 30.0
    """Largest angle (deg) between an edge's projected 3D direction and its image line."""
    loss: str = "soft_l1"
    """Robust loss of :func:`scipy.optimize.least_squares`."""
    loss_scale_px: float = 1.0
    """Residual (px) where the robust loss starts to down-weight, in the final rounds."""
    loss_scale_share: float = 0.25
    """In rounds with wide match radii the loss starts to down-weight at this share of the radius (when that is
    more than ``loss_scale_px``), so that matches still several pixels off pull the estimate in."""
    max_nfev: int = 100
    """Most residual evaluations per least-squares round."""
    translation_prior_m: float | None = None
    """1-sigma (m, per axis) of the translation of ``T_init`` taken as a measurement, or None for none. For
    scenes whose edges are all far: 1 cm at 20 m is about 1 px, so edges there fix the rotation far better than
    the translation, which a measured mounting then holds."""


@dataclass
class EdgeMatches:
    """LiDAR edge points matched to local image lines, stacked over pairs; row ``i`` of each array is one match."""

    points: np.ndarray
    """(M, 3) LiDAR edge points (m, LiDAR frame)."""
    centre: np.ndarray
    """(M, 2) a point of each one's image line (px)."""
    normal: np.ndarray
    """(M, 2) the unit normal of each one's image line."""
    pair: np.ndarray
    """(M,) int index of the pair of each match."""

    def __len__(self) -> int:
        return len(self.points)

    @classmethod
    def stack(cls, matches: list[EdgeMatches]) -> EdgeMatches:
        return cls(np.vstack([m.points for m in matches]), np.vstack([m.centre for m in matches]),
                   np.vstack([m.normal for m in matches]), np.concatenate([m.pair for m in matches]))

    def subset(self, keep: np.ndarray) -> EdgeMatches:
        return EdgeMatches(self.points[keep], self.centre[keep], self.normal[keep], self.pair[keep])

    def residuals(self, T_camera_lidar: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
        """(M,) signed distances (px) of the projected points from their image lines."""
        uv = camera.project(transform_points(T_camera_lidar, self.points))
        return np.einsum("ij,ij->i", self.normal, uv - self.centre)

    def jacobian(self, T_ref: np.ndarray, p: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
        """(M, 6) derivatives of :meth:`residuals` at ``apply_params(T_ref, p)`` (px per m and per rad).

        A residual ``n . pi(X)`` with ``X = R p + t`` and ``R = R_ref Exp(w)`` has ``d/dt = g`` and
        ``d/dw = -((R^T g) x p)^T J_r(w)`` with ``g = n^T d(pi)/dX``.
        """
        T = apply_params(T_ref, p)
        _, d_project = project_with_jacobian(camera, transform_points(T, self.points))
        g = np.einsum("mi,mij->mj", self.normal, d_project)
        return np.hstack([g, -np.cross(g @ T[:3, :3], self.points) @ right_jacobian(p[3:])])


def project_with_jacobian(camera: CameraIntrinsics, points_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of (N, 3) camera-frame points (m) and their derivatives d(u, v)/d(x, y, z) (N, 2, 3) (px/m).

    The pinhole division is differentiated analytically; the lens's 2x2 derivative is a central difference
    of :meth:`~backend.core.camera.CameraIntrinsics.normalised_to_pixels`, which writes out both camera models:
    no distortion formula is written twice, and the difference is exact to about 1e-6 of its value.
    """
    x, y, z = points_camera.T
    xn, yn = x / z, y / z
    u, v = camera.normalised_to_pixels(xn, yn)
    eps = 1e-6
    d_dx = np.subtract(camera.normalised_to_pixels(xn + eps, yn), camera.normalised_to_pixels(xn - eps, yn))
    d_dy = np.subtract(camera.normalised_to_pixels(xn, yn + eps), camera.normalised_to_pixels(xn, yn - eps))
    d_lens = np.stack([d_dx, d_dy], axis=-1).transpose(1, 0, 2) / (2 * eps)  # (N, 2 (u, v), 2 (x, y))
    d_pinhole = np.zeros((len(z), 2, 3))
    d_pinhole[:, 0, 0] = d_pinhole[:, 1, 1] = 1 / z
    d_pinhole[:, 0, 2], d_pinhole[:, 1, 2] = -xn / z, -yn / z
    return np.column_stack([u, v]), d_lens @ d_pinhole


def match_edges(points_lidar: np.ndarray, directions: np.ndarray, image: ImageEdges, T_camera_lidar: np.ndarray,
                camera: CameraIntrinsics, radius_px: float, settings: FineAlignmentSettings, pair: int = 0
                ) -> tuple[EdgeMatches, int]:
    """One pair's matches at ``T_camera_lidar`` and how many of its LiDAR edge points the camera sees.

    ``points_lidar`` (N, 3, m) are the LiDAR edge points and ``directions`` (N, 3) their unit 3D directions,
    NaN where unknown (no direction check); ``pair`` is stored with each match.
    """
    projection = project_cloud(points_lidar, T_camera_lidar, camera)
    distance, neighbour = image.tree.query(projection.uv, k=settings.neighbours, distance_upper_bound=radius_px)
    found = np.isfinite(distance).all(axis=1)
    index = projection.index[found]
    pixels = image.pixels[neighbour[found]]  # (M, k, 2)
    centre = pixels.mean(axis=1)
    offsets = pixels - centre[:, None]
    eigenvalues, eigenvectors = np.linalg.eigh(np.einsum("mki,mkj->mij", offsets, offsets) / settings.neighbours)
    normal, along = eigenvectors[:, :, 0], eigenvectors[:, :, 1]
    good = np.sqrt(np.clip(eigenvalues[:, 0], 0, None)) <= settings.max_line_rms_px
    known = np.flatnonzero(np.isfinite(directions[index]).all(axis=1))
    if len(known):
        _, d_project = project_with_jacobian(camera, transform_points(T_camera_lidar, points_lidar[index[known]]))
        image_direction = np.einsum("nij,nj->ni", d_project, directions[index[known]] @ T_camera_lidar[:3, :3].T)
        image_direction /= np.linalg.norm(image_direction, axis=1, keepdims=True) + 1e-12
        cos_angle = np.abs(np.einsum("ij,ij->i", image_direction, along[known]))
        good[known] &= cos_angle >= np.cos(np.radians(settings.max_direction_angle_deg))
    matches = EdgeMatches(points_lidar[index[good]], centre[good], normal[good], np.full(np.count_nonzero(good), pair))
    return matches, len(projection)


def solve_matches(T_ref: np.ndarray, matches: EdgeMatches, camera: CameraIntrinsics, settings: FineAlignmentSettings,
                  loss_scale_px: float, t_prior: np.ndarray) -> OptimizeResult:
    """Robust least squares of the point-to-line distances about ``T_ref``; ``result.x`` are the parameters.

    With :attr:`~FineAlignmentSettings.translation_prior_m` set, ``t_prior`` (m, camera axes; the translation
    of ``T_init``) is a measurement: three more residuals ``(t - t_prior) / sigma`` in units of
    ``settings.loss_scale_px``, so that one sigma of the prior weighs like one pixel of an edge's residual. The robust
    loss is for the edges only (:func:`robust_then_quadratic`).
    """
    sigma = settings.translation_prior_m
    weight = 0.0 if sigma is None else settings.loss_scale_px / sigma  # px per m
    offset = T_ref[:3, 3] - t_prior
    prior_jacobian = np.hstack([weight * np.eye(3), np.zeros((3, 3))])
    return least_squares(
        lambda p: np.r_[matches.residuals(apply_params(T_ref, p), camera), weight * (offset + p[:3])], np.zeros(6),
        jac=lambda p: np.vstack([matches.jacobian(T_ref, p, camera), prior_jacobian]),
        loss=robust_then_quadratic(settings.loss, len(matches)), f_scale=loss_scale_px, max_nfev=settings.max_nfev)


def _soft_l1(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = 1.0 + z
    return 2.0 * (np.sqrt(t) - 1.0), t**-0.5, -0.5 * t**-1.5


def _cauchy(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.log1p(z), 1.0 / (1.0 + z), -1.0 / (1.0 + z) ** 2


def _linear(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return z, np.ones_like(z), np.zeros_like(z)


ROBUST_LOSSES = {"linear": _linear, "soft_l1": _soft_l1, "cauchy": _cauchy}
"""The losses :attr:`FineAlignmentSettings.loss` may name: SciPy's of those names, ``rho(z)`` of the squared scaled
residual ``z`` with its first two derivatives."""


def robust_then_quadratic(loss: str, n_robust: int) -> Callable[[np.ndarray], np.ndarray]:
    """A :func:`scipy.optimize.least_squares` loss that is ``loss`` (:data:`ROBUST_LOSSES`) on the first ``n_robust``
    residuals (the edges) and quadratic on the rest (a prior): a measurement with a Gaussian sigma. Under a robust
    loss its pull is bounded, so that enough edges drag a held translation anywhere (10 cm from the guess under a
    1 mm prior, on the simulated board scene). SciPy applies one named loss to every residual, hence this."""
    robust = ROBUST_LOSSES[loss]

    def rho(z: np.ndarray) -> np.ndarray:
        out = np.empty((3, len(z)))
        out[:, :n_robust] = robust(z[:n_robust])
        out[:, n_robust:] = _linear(z[n_robust:])
        return out

    return rho
