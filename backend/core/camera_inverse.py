"""Exact inverse of the camera models, and the widest ray a camera's image sees.

OpenCV's ``undistortPoints`` runs a fixed handful of fixed-point iterations, which
is far from converged for strongly distorted lenses near the image corners;
:func:`undistort_exact` refines it with Newton steps on
:meth:`CameraIntrinsics.project_normalised`. :func:`visible_radius` bounds the
normalised radius whose projection is meaningful: beyond it a distortion polynomial
may fold points back into the image.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from backend.core.camera import CameraIntrinsics, CameraModelName
from backend.core.splined import SplineGrid

CameraKey = tuple[CameraModelName, int, int, tuple[float, ...], tuple[float, ...], SplineGrid | None]
"""A camera's parameters as a hashable cache key: model, width, height, K (row-major), dist, spline grid."""


def undistort_exact(camera: CameraIntrinsics, pixels: np.ndarray, iterations: int = 10) -> np.ndarray:
    """Normalised coordinates (N, 2) (x/z, y/z) of distorted pixels (N, 2, px), solved to 1e-6 px.

    Starts from :meth:`CameraIntrinsics.undistort_points` and refines with Newton
    steps on :meth:`CameraIntrinsics.project_normalised` (finite-difference Jacobian).
    Raises ``ValueError`` if some pixel has no inverse (the lens model folds over).
    """
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    xy = camera.undistort_points(pixels)
    eps = 1e-7
    with np.errstate(divide="ignore", invalid="ignore"):  # a pixel with no inverse ends non-finite: refused below
        for _ in range(iterations):
            uv = camera.project_normalised(xy)
            residual = pixels - uv
            if np.max(np.abs(residual)) < 1e-7:
                break
            d_dx = (camera.project_normalised(xy + [eps, 0.0]) - uv) / eps
            d_dy = (camera.project_normalised(xy + [0.0, eps]) - uv) / eps
            det = d_dx[:, 0] * d_dy[:, 1] - d_dy[:, 0] * d_dx[:, 1]
            step_x = (d_dy[:, 1] * residual[:, 0] - d_dy[:, 0] * residual[:, 1]) / det
            step_y = (d_dx[:, 0] * residual[:, 1] - d_dx[:, 1] * residual[:, 0]) / det
            xy = xy + np.column_stack([step_x, step_y])
        error_px = np.max(np.linalg.norm(pixels - camera.project_normalised(xy), axis=1))
    if not error_px < 1e-6:
        raise ValueError(f"camera model cannot be inverted over the image (residual {error_px:.2g} px)")
    return xy


FOLD_SEARCH_MAX_DEG = 89.0
"""The fold search (:func:`fold_radius`) looks up to this angle off the optical axis (deg): a normalised radius
(x/z) cannot hold 90 deg."""
FOLD_SEARCH_STEPS = 4000
"""Angles sampled by the fold search (0.02 deg apart)."""


def visible_radius(camera: CameraIntrinsics) -> float:
    """Largest normalised radius (tan of the angle off the optical axis) any pixel of ``camera`` sees.

    Taken at the image corners, which is where it is for radial lenses, and never beyond where the lens model
    folds over (:func:`fold_radius`): a loosely fitted polynomial (the shared VLP-16 set's fisheye, whose
    coefficients have sigmas up to 37) may peak before the corners, which then have no inverse. Cached.
    """
    return _visible_radius_cached(camera_key(camera))


def camera_key(camera: CameraIntrinsics) -> CameraKey:
    """``camera``'s parameters as a hashable cache key."""
    return camera.model, camera.width, camera.height, tuple(camera.K.ravel()), tuple(camera.dist), camera.spline


def camera_from_key(key: CameraKey) -> CameraIntrinsics:
    """The camera of a :func:`camera_key`."""
    model, width, height, K, dist, spline = key
    return CameraIntrinsics(model, width, height, np.reshape(K, (3, 3)), np.array(dist), spline)


@lru_cache(maxsize=8)
def _visible_radius_cached(key: CameraKey) -> float:
    camera = camera_from_key(key)
    w, h = camera.width - 1, camera.height - 1
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=float)
    fold = fold_radius(camera, corners)
    try:
        return min(fold, float(np.max(np.linalg.norm(undistort_exact(camera, corners), axis=1))))
    except ValueError:  # a corner lies beyond the fold
        return fold


def fold_radius(camera: CameraIntrinsics, corners: np.ndarray) -> float:
    """The normalised radius where ``camera``'s model stops moving a point outwards, toward any of the image's
    ``corners`` (N, 2, px): the first sampled angle off the axis whose pixel lies no farther from the principal
    point than the previous one's, or :data:`FOLD_SEARCH_MAX_DEG` when the model never folds."""
    centre = camera.K[:2, 2]
    focal = np.diag(camera.K)[:2]
    directions = (corners - centre) / focal
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = np.tan(np.radians(np.linspace(0.0, FOLD_SEARCH_MAX_DEG, FOLD_SEARCH_STEPS)))
    xy = radii[None, :, None] * directions[:, None, :]
    pixels = camera.project_normalised(xy.reshape(-1, 2)).reshape(len(directions), len(radii), 2)
    # outward from where the axis itself lands (the principal point, but for a spline's correction there)
    outward = np.diff(np.linalg.norm(pixels - pixels[:, :1], axis=2), axis=1) > 0
    if outward.all():
        return float(radii[-1])
    return float(radii[np.argmin(outward, axis=1)[~outward.all(axis=1)].min()])
