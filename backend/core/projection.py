"""LiDAR (or any) points drawn onto a camera image, and image colours taken onto the points.

Geometry only: :func:`project_cloud` maps points from a sensor frame into a camera's
pixels (frames and pixels as in ``conventions.md``: ``T_camera_sensor`` maps sensor
points into the camera's optical frame, x right, y down, z forward; the centre of
the top-left pixel is (0, 0), so the image spans ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``),
dropping what the camera cannot see and, optionally, what a nearer surface hides.
:mod:`backend.core.colour_maps` colours the kept points (by depth, intensity or height, on
TURBO), :func:`draw_points` paints them into the image, and
:func:`colourise_cloud` is the reverse view: each point takes its pixel's colour.

Works the same for a 3D LiDAR, a 2D scanner (points with z = 0 in its frame) and a
depth camera's points.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import visible_radius

MIN_DEPTH_M = 1e-3
"""Points nearer than this (z in the camera frame, m) count as behind the camera."""
OCCLUSION_MARGIN = 0.05
"""A point is hidden if it lies more than this fraction of the nearest depth behind the
nearest point of its pixel block (5 %: 10 cm at 2 m, 1 m at 20 m). Relative, because the
depth spread a slanted surface covers within one block grows with its distance."""


@dataclass
class Projection:
    """The points of a cloud a camera sees, row ``i`` of each array being one point."""

    uv: np.ndarray
    """(M, 2) float64 pixel coordinates (u right, v down, px)."""
    depth_m: np.ndarray
    """(M,) float64 z of each point in the camera's optical frame (m)."""
    index: np.ndarray
    """(M,) int64 row of each point in the input cloud."""

    def __len__(self) -> int:
        return len(self.index)


def project_cloud(
    points_sensor: np.ndarray,
    T_camera_sensor: np.ndarray,
    camera: CameraIntrinsics,
    *,
    range_m: tuple[float, float] | None = None,
    occlusion_px: int = 0,
    occlusion_margin: float = OCCLUSION_MARGIN,
) -> Projection:
    """Project (N, 3) points in a sensor's frame (m) into ``camera``, keeping those it sees.

    Dropped: NaN / inf points; points behind the camera (z <= :data:`MIN_DEPTH_M`);
    points whose normalised radius (tan of the angle off the optical axis) exceeds what
    the image corners reach (:func:`~backend.core.camera_inverse.visible_radius`), since
    a strong distortion polynomial folds such points back into the image; points that
    land outside the image; with ``range_m = (lo, hi)``, points whose Euclidean range
    from the *sensor's* origin (m) is outside ``[lo, hi]``; with ``occlusion_px > 0``,
    points hidden by a nearer surface: the image is cut into ``occlusion_px``-sized
    square blocks and a block keeps only the points within ``occlusion_margin`` (a
    fraction of depth) of its nearest one.
    """
    points = np.asarray(points_sensor, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(T_camera_sensor, dtype=np.float64)
    # (3, N): each coordinate is a contiguous row, so every step below runs on 1-D arrays.
    with np.errstate(invalid="ignore"):  # NaN points are expected, and dropped below
        cam = T[:3, :3] @ points.T
    cam += T[:3, 3:]
    x, y, z = cam
    # In front, and within the cone the image corners reach ((x/z)^2 + (y/z)^2 <= r^2, as z > 0):
    # beyond it the distortion may fold points back in. The sum is NaN or inf if any coordinate is.
    in_cone = (z > MIN_DEPTH_M) & np.isfinite(x + y + z) & (x * x + y * y <= visible_radius(camera) ** 2 * (z * z))
    index = np.flatnonzero(in_cone)
    x, y, z = np.take(cam, index, axis=1)  # 3x faster than cam[:, index]
    if range_m is not None:
        # The range from the sensor's origin, which sits at T's translation in the camera frame.
        t = T[:3, 3]
        r2 = (x - t[0]) ** 2 + (y - t[1]) ** 2 + (z - t[2]) ** 2
        index, x, y, z = _keep((r2 >= range_m[0] ** 2) & (r2 <= range_m[1] ** 2), index, x, y, z)
    x /= z
    y /= z
    u, v = camera.normalised_to_pixels(x, y)
    index, u, v, z = _keep(_in_image(u, v, camera.width, camera.height), index, u, v, z)
    if occlusion_px > 0:
        near = _unoccluded(u, v, z, camera.width, occlusion_px, occlusion_margin)
        index, u, v, z = _keep(near, index, u, v, z)
    return Projection(np.column_stack([u, v]), z, index)


def _in_image(u: np.ndarray, v: np.ndarray, width: int, height: int) -> np.ndarray:
    """Whether pixel coordinates (px) fall on the image, ``[-0.5, width - 0.5) x [-0.5, height - 0.5)``; NaN do not."""
    return (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)


def _keep(mask: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each of ``arrays`` (same length as ``mask``) restricted to where ``mask`` holds."""
    rows = np.flatnonzero(mask)
    return tuple(a[rows] for a in arrays)


def _unoccluded(u: np.ndarray, v: np.ndarray, depth_m: np.ndarray, width: int, block_px: int,
                margin: float) -> np.ndarray:
    """Whether each point (pixels inside the image, depth in m) is within ``margin`` of its block's nearest depth."""
    cols = (u + 0.5).astype(np.int64) // block_px  # u >= -0.5, so truncation is the floor
    rows = (v + 0.5).astype(np.int64) // block_px
    block = rows * (-(-width // block_px)) + cols
    nearest = np.full(int(block.max()) + 1 if len(block) else 0, np.inf)
    np.minimum.at(nearest, block, depth_m)  # a z-buffer over blocks, unbuffered so repeated blocks all count
    return depth_m <= nearest[block] * (1.0 + margin)


def draw_points(image: np.ndarray, uv: np.ndarray, colours: np.ndarray, radius_px: int = 1) -> np.ndarray:
    """A BGR uint8 copy of ``image`` (BGR or gray) with points at ``uv`` (M, 2, px) painted in ``colours``.

    ``colours`` is (M, 3) uint8 RGB, as the colour functions here give. Each point is a
    square of side ``2 * radius_px + 1`` centred on its nearest pixel; where squares
    overlap, the later point is on top (as if painted in order). Instead of writing
    ``(2r + 1)**2`` shifted copies of every point, each point is written once into a
    layer whose value packs (order, colour) and the layer is grey-dilated with a square
    kernel: the dilation's maximum picks the last point covering a pixel, and the cost
    is one pass over the image whatever the number of points.
    """
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    height, width = canvas.shape[:2]
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    inside = np.flatnonzero(_in_image(uv[:, 0], uv[:, 1], width, height))
    cols, rows = _pixels(uv[inside])
    rgb = np.asarray(colours, dtype=np.uint8).reshape(-1, 3)[inside].astype(np.int64)
    # order * 2**24 + 0xRRGGBB, exact in float64 below 2**53 (2**29 points); 0 means "no point".
    key = ((np.arange(1, len(inside) + 1) << 24) | (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).astype(np.float64)
    layer = np.zeros(height * width)
    np.maximum.at(layer, rows * width + cols, key)
    side = 2 * int(radius_px) + 1
    layer = cv2.dilate(layer.reshape(height, width), np.ones((side, side), np.uint8))
    painted = layer > 0
    packed = layer[painted].astype(np.int64)
    canvas[painted] = np.column_stack([packed & 255, (packed >> 8) & 255, (packed >> 16) & 255]).astype(np.uint8)
    return canvas


def colourise_cloud(
    points_sensor: np.ndarray,
    T_camera_sensor: np.ndarray,
    camera: CameraIntrinsics,
    image: np.ndarray,
    *,
    occlusion_px: int = 4,
    range_m: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Colour each of (N, 3) sensor-frame points (m) by the pixel of ``image`` (BGR or gray) it projects to.

    Returns ``(colours, seen)``: (N, 3) uint8 RGB (nearest pixel; zeros where unseen) and
    an (N,) bool that is False for points the camera does not see (see
    :func:`project_cloud`; ``occlusion_px`` keeps hidden points from taking the colour
    of the surface in front of them).
    """
    projection = project_cloud(points_sensor, T_camera_sensor, camera, range_m=range_m, occlusion_px=occlusion_px)
    bgr = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image
    cols, rows = _pixels(projection.uv)
    n = len(np.asarray(points_sensor).reshape(-1, 3))
    colours = np.zeros((n, 3), np.uint8)
    colours[projection.index] = bgr[rows, cols, ::-1]
    seen = np.zeros(n, bool)
    seen[projection.index] = True
    return colours, seen


def _pixels(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (int64) of the pixel nearest each of (M, 2) pixel coordinates (px)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    return np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
