"""Render a calibration board as a simulated camera sees it.

Every sub-pixel's exact ray through the distorted lens (:mod:`backend.sim.camera_rays`)
is intersected with the board plane (z = 0 in the board frame). The hit point is
looked up in a mip-mapped texture of the printed board (trilinear: the level whose
texel matches the sub-pixel's footprint), then 2x2 sub-pixels are averaged per
pixel. The result is composited over a textured background, lit with a smooth
gradient and vignetting, blurred and given sensor noise.

The board is printed on a white plate that extends :data:`PLATE_MARGIN_SQUARES`
squares beyond the pattern on every side; the board frame is the one of
:class:`BoardSpec` (origin at the first inner corner, x along the columns, y along
the rows, z into the board, metres), so the camera sees the print from board z < 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import transform_points
from backend.sim.camera_rays import RayField, ray_field

PLATE_MARGIN_SQUARES = 1.0
"""White margin of the plate around the printed pattern, in squares."""
SUPERSAMPLE = 2
"""Sub-pixels per pixel along each axis."""
TEXELS_PER_SQUARE = 256
"""Resolution of the finest texture level (a power of two; each mip level halves it)."""
PAPER_REFLECTANCE = 0.85
"""Fraction of light the white paper reflects (0..1)."""
INK_REFLECTANCE = 0.06
"""Fraction of light the black print reflects (0..1)."""
_TEXTURE_ONE = 65535.0
"""uint16 texture value standing for 1.0."""


@dataclass(frozen=True)
class _PlateTexture:
    """Mip-mapped texture of the plate: per level (h, w, 2) uint16 of premultiplied reflectance and coverage."""

    levels: tuple[np.ndarray, ...]
    corners_m: np.ndarray
    """(4, 3) board-frame plate corners (m), as :func:`plate_corners_m`."""
    texels_per_m: float
    """Texels per metre of level 0."""


def plate_corners_m(board: BoardSpec) -> np.ndarray:
    """(4, 3) board-frame corners of the plate, print plus white margin (m): TL, TR, BR, BL."""
    margin = PLATE_MARGIN_SQUARES * board.square_m
    x0, y0 = board.outer_origin_m[:2] - margin
    x1, y1 = x0 + board.size_m[0] + 2 * margin, y0 + board.size_m[1] + 2 * margin
    return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


def render_board_image(
    camera: CameraIntrinsics,
    board: BoardSpec,
    T_camera_board: np.ndarray,
    rng: np.random.Generator,
    *,
    blur_px: float = 0.7,
    noise_sigma: float = 2.0,
    brightness: float | None = None,
    gradient: float | None = None,
    vignetting: float = 0.2,
) -> np.ndarray:
    """A uint8 grayscale (H, W) image of ``board`` at pose ``T_camera_board`` (board to optical frame, m).

    Args:
        camera: the simulated camera; its distortion is rendered exactly.
        board: the board printed on the plate (checkerboard or ChArUco).
        T_camera_board: 4x4 pose of the board in the camera's optical frame (m).
            A board seen from behind, or not wholly in front of the camera, is
            not drawn.
        rng: the only source of randomness (lighting, background, noise).
        blur_px: sigma of the Gaussian lens blur (px); 0 for none.
        noise_sigma: sigma of the additive Gaussian sensor noise (grey levels).
        brightness: grey level a perfectly white surface would have at the image
            centre; drawn from 160..230 when None.
        gradient: relative change of the illumination from the centre to the image
            corners along a random direction; drawn from 0..0.2 when None.
        vignetting: relative darkening at the image corners.
    """
    rays = ray_field(camera, SUPERSAMPLE)
    if brightness is None:
        brightness = rng.uniform(160.0, 230.0)
    if gradient is None:
        gradient = rng.uniform(0.0, 0.2)
    gradient_angle = rng.uniform(0.0, 2 * np.pi)
    reflectance = _background(rng, camera.width, camera.height)
    plate = _render_plate(rays, _plate_texture(board), np.asarray(T_camera_board, dtype=float))
    if plate is not None:
        premultiplied, coverage, rows, cols = plate
        reflectance[rows, cols] = reflectance[rows, cols] * (1.0 - coverage) + premultiplied
    illumination = _illumination(camera.width, camera.height, brightness, gradient, gradient_angle, vignetting)
    radiance = reflectance * illumination
    if blur_px > 0:
        radiance = cv2.GaussianBlur(radiance, (0, 0), blur_px)
    radiance += noise_sigma * rng.standard_normal(radiance.shape, dtype=np.float32)
    return np.clip(np.rint(radiance), 0, 255).astype(np.uint8)


def _render_plate(
    rays: RayField, texture: _PlateTexture, T_camera_board: np.ndarray
) -> tuple[np.ndarray, np.ndarray, slice, slice] | None:
    """Premultiplied reflectance and coverage (both (h, w) float32) of the plate over its pixel box.

    Returns None unless the printed side faces the camera and the whole plate is in
    front of it (z > 0 in the optical frame).
    """
    plate_camera = transform_points(T_camera_board, texture.corners_m)
    t_board_camera = -T_camera_board[:3, :3].T @ T_camera_board[:3, 3]
    if t_board_camera[2] >= 0 or np.any(plate_camera[:, 2] <= 0):
        return None
    H_texel_ray = _texel_homography(texture, T_camera_board)
    box = _plate_pixel_box(rays, texture, H_texel_ray)
    if box is None:
        return None
    rows, cols = box
    s = rays.supersample
    sub_xy = rays.xy[rows.start * s : rows.stop * s, cols.start * s : cols.stop * s]
    h, w = rows.stop - rows.start, cols.stop - cols.start
    level = _mip_level(cv2.perspectiveTransform(np.ascontiguousarray(sub_xy[::s, ::s]), H_texel_ray), s, texture)
    pixels = np.zeros((h, w, 2), np.float32)
    for k in range(int(np.floor(level.min())), int(np.ceil(level.max())) + 1):
        weight = np.clip(1.0 - np.abs(level - k), 0.0, 1.0)
        used_rows, used_cols = (np.flatnonzero(np.any(weight > 0, axis=axis)) for axis in (1, 0))
        if used_rows.size == 0:
            continue
        r, c = slice(used_rows[0], used_rows[-1] + 1), slice(used_cols[0], used_cols[-1] + 1)
        # Texel centres of level k sit at level-0 coordinates (i + 0.5) * 2**k - 0.5.
        scale = 0.5**k
        H_level_ray = np.array([[scale, 0, 0.5 * scale - 0.5], [0, scale, 0.5 * scale - 0.5], [0, 0, 1]]) @ H_texel_ray
        texel_map = cv2.perspectiveTransform(sub_xy[r.start * s : r.stop * s, c.start * s : c.stop * s], H_level_ray)
        lookup = cv2.remap(texture.levels[k], texel_map, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        box_size = (c.stop - c.start, r.stop - r.start)
        pixels[r, c] += weight[r, c, None] * cv2.resize(lookup, box_size, interpolation=cv2.INTER_AREA)
    pixels /= _TEXTURE_ONE
    return pixels[..., 0], pixels[..., 1], rows, cols


def _texel_homography(texture: _PlateTexture, T_camera_board: np.ndarray) -> np.ndarray:
    """3x3 homography from normalised image coordinates (x/z, y/z) to level-0 texel coordinates.

    Texel centres are at integer coordinates. Rays meeting the board plane behind the
    camera map to points that are not on the plate, as long as the plate is wholly
    in front of the camera.
    """
    R_board_camera = T_camera_board[:3, :3].T
    t_board_camera = -R_board_camera @ T_camera_board[:3, 3]
    # A ray d meets z = 0 at t + lambda * R d with lambda = -t_z / (R d)_z, so the hit
    # point is ((t_x R_z - t_z R_x) d, (t_y R_z - t_z R_y) d) / (R_z d).
    r_x, r_y, r_z = R_board_camera
    t_x, t_y, t_z = t_board_camera
    H_board_ray = np.array([t_x * r_z - t_z * r_x, t_y * r_z - t_z * r_y, r_z])
    # Texel (0, 0) is centred half a texel inside the plate's top-left corner (x0, y0).
    texel = texture.texels_per_m
    x0, y0 = texture.corners_m[0, :2]
    H_texel_board = np.array([[texel, 0, -0.5 - x0 * texel], [0, texel, -0.5 - y0 * texel], [0, 0, 1]])
    return H_texel_board @ H_board_ray


def _plate_pixel_box(rays: RayField, texture: _PlateTexture, H_texel_ray: np.ndarray) -> tuple[slice, slice] | None:
    """Row and column slices (px) of the image that hold the plate, found on the coarse ray nodes."""
    texel_uv = cv2.perspectiveTransform(rays.node_xy, H_texel_ray)
    height_tex, width_tex = texture.levels[0].shape[:2]
    inside = (texel_uv[..., 0] >= -0.5) & (texel_uv[..., 0] <= width_tex - 0.5)
    inside &= (texel_uv[..., 1] >= -0.5) & (texel_uv[..., 1] <= height_tex - 0.5)
    node_rows, node_cols = np.nonzero(inside)
    if node_rows.size == 0:
        return None
    height, width = rays.xy.shape[0] // rays.supersample, rays.xy.shape[1] // rays.supersample
    v0 = rays.node_v[max(node_rows.min() - 1, 0)]
    v1 = rays.node_v[min(node_rows.max() + 1, len(rays.node_v) - 1)]
    u0 = rays.node_u[max(node_cols.min() - 1, 0)]
    u1 = rays.node_u[min(node_cols.max() + 1, len(rays.node_u) - 1)]
    rows = slice(int(np.clip(np.floor(v0), 0, height)), int(np.clip(np.ceil(v1) + 1, 0, height)))
    cols = slice(int(np.clip(np.floor(u0), 0, width)), int(np.clip(np.ceil(u1) + 1, 0, width)))
    if rows.start >= rows.stop or cols.start >= cols.stop:
        return None
    return rows, cols


def _mip_level(texel_uv: np.ndarray, supersample: int, texture: _PlateTexture) -> np.ndarray:
    """Fractional mip level (float32, per pixel) whose texel spans one sub-pixel's footprint (longer axis).

    ``texel_uv`` (h, w, 2) holds level-0 texel coordinates at pixel spacing. The
    range of levels is that of the pixels that see the plate; the other pixels
    (whose footprint may be meaningless near the horizon) are clamped into it.
    """
    d_drow, d_dcol = np.gradient(texel_uv, axis=(0, 1))
    footprint_sq = np.maximum(np.sum(d_dcol**2, axis=2), np.sum(d_drow**2, axis=2))
    level = 0.5 * np.log2(np.maximum(footprint_sq, 1e-12)) - np.log2(supersample)
    height, width = texture.levels[0].shape[:2]
    u, v = texel_uv[..., 0], texel_uv[..., 1]
    on_plate = (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    lowest, highest = (level[on_plate].min(), level[on_plate].max()) if on_plate.any() else (0.0, 0.0)
    return np.clip(level, max(lowest, 0.0), min(highest, len(texture.levels) - 1.0))


@lru_cache(maxsize=4)
def _plate_texture(board: BoardSpec) -> _PlateTexture:
    """The (cached) mip-mapped texture of the plate carrying ``board``, down to one texel per square."""
    pattern = board.render(TEXELS_PER_SQUARE).astype(np.float32) / 255.0
    reflectance = INK_REFLECTANCE + (PAPER_REFLECTANCE - INK_REFLECTANCE) * pattern
    margin = int(round(PLATE_MARGIN_SQUARES * TEXELS_PER_SQUARE))
    reflectance = np.pad(reflectance, margin, constant_values=PAPER_REFLECTANCE)
    level = np.rint(np.dstack([reflectance, np.ones_like(reflectance)]) * _TEXTURE_ONE).astype(np.uint16)
    levels = [level]
    for _ in range(int(np.log2(TEXELS_PER_SQUARE))):
        level = cv2.resize(level, (level.shape[1] // 2, level.shape[0] // 2), interpolation=cv2.INTER_AREA)
        levels.append(level)
    return _PlateTexture(tuple(levels), plate_corners_m(board), TEXELS_PER_SQUARE / board.square_m)


def _background(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """Mid-grey reflectance (H, W) float32: multi-scale smooth blotches over a wall/floor step."""
    reflectance = np.full((height, width), rng.uniform(0.38, 0.5), np.float32)
    for cells, amplitude in ((3, 0.10), (12, 0.05), (48, 0.025)):
        coarse = rng.standard_normal((max(2, cells * height // width), cells)).astype(np.float32)
        reflectance += amplitude * cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    horizon = rng.uniform(0.2, 0.8) * height
    rows = np.arange(height, dtype=np.float32)[:, None]
    step = 0.5 + 0.5 * np.tanh((rows - horizon) / 12.0)
    reflectance += rng.uniform(-0.12, 0.12) * step
    return np.clip(reflectance, 0.05, 0.9)


def _illumination(
    width: int, height: int, brightness: float, gradient: float, angle_rad: float, vignetting: float
) -> np.ndarray:
    """Radiance (grey levels) of a white surface at each pixel: linear gradient times radial vignetting."""
    half_diagonal = 0.5 * np.hypot(width, height)
    x = ((np.arange(width, dtype=np.float32) - (width - 1) / 2) / half_diagonal)[None, :]
    y = ((np.arange(height, dtype=np.float32) - (height - 1) / 2) / half_diagonal)[:, None]
    ramp = 1.0 + gradient * (np.cos(angle_rad) * x + np.sin(angle_rad) * y)
    return np.float32(brightness) * ramp * (1.0 - vignetting * (x**2 + y**2))
