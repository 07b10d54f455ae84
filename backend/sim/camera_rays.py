"""Exact viewing rays of every (sub-)pixel of a camera, cached per camera.

The renderer needs rays that :meth:`CameraIntrinsics.project` maps back onto the
pixel to well under 0.01 px, so rays are computed exactly
(:func:`~backend.core.camera_inverse.undistort_exact`) on a coarse node grid and
interpolated with a bicubic spline on the sub-pixel grid. The ray field is smooth,
so the spline is exact to about 1e-5 px.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.interpolate import RectBivariateSpline

from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import CameraKey, camera_from_key, camera_key, undistort_exact

NODE_STEP_PX = 8
"""Spacing of the coarse grid on which rays are solved exactly (px)."""


@dataclass(frozen=True)
class RayField:
    """Normalised image coordinates (x/z, y/z) of the rays through a camera's sub-pixels.

    The sub-pixel grid has ``supersample`` x ``supersample`` samples per pixel; sample
    ``(row, col)`` sits at pixel coordinates ``((col + 0.5) / s - 0.5, (row + 0.5) / s - 0.5)``,
    so pixel ``(v, u)`` is covered by rows ``s*v .. s*v+s-1`` and columns ``s*u .. s*u+s-1``.
    """

    supersample: int
    xy: np.ndarray
    """(s*H, s*W, 2) float32 normalised coordinates (x/z, y/z) of each sub-pixel ray."""
    node_u: np.ndarray
    """(nu,) pixel x of the coarse nodes (px); they extend two steps beyond the image."""
    node_v: np.ndarray
    """(nv,) pixel y of the coarse nodes (px)."""
    node_xy: np.ndarray
    """(nv, nu, 2) exact normalised coordinates at the coarse nodes."""


def ray_field(camera: CameraIntrinsics, supersample: int) -> RayField:
    """The :class:`RayField` of ``camera`` with ``supersample`` x ``supersample`` rays per pixel.

    Cached on the camera's parameters: computing it takes about 0.2 s.
    """
    return _ray_field_cached(camera_key(camera), supersample)


@lru_cache(maxsize=8)
def _ray_field_cached(key: CameraKey, supersample: int) -> RayField:
    camera = camera_from_key(key)
    width, height = camera.width, camera.height
    node_u = np.arange(-2 * NODE_STEP_PX, width + 2 * NODE_STEP_PX + 1, NODE_STEP_PX, dtype=float)
    node_v = np.arange(-2 * NODE_STEP_PX, height + 2 * NODE_STEP_PX + 1, NODE_STEP_PX, dtype=float)
    grid_u, grid_v = np.meshgrid(node_u, node_v)
    node_xy = undistort_exact(camera, np.column_stack([grid_u.ravel(), grid_v.ravel()])).reshape(len(node_v), -1, 2)
    sub_u = (np.arange(width * supersample) + 0.5) / supersample - 0.5
    sub_v = (np.arange(height * supersample) + 0.5) / supersample - 0.5
    xy = np.dstack(
        [RectBivariateSpline(node_v, node_u, node_xy[..., i], kx=3, ky=3)(sub_v, sub_u) for i in range(2)]
    ).astype(np.float32)
    return RayField(supersample, xy, node_u, node_v, node_xy)
