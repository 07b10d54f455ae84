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
from backend.sim.camera_rays import RayField, ray_field

PLATE_MARGIN_SQUARES = 1.0
"""White margin of the plate around the printed pattern, in squares."""
SUPERSAMPLE = 2
"""Sub-pixels per pixel along each axis."""
TEXELS_PER_SQUARE = 256
"""Resolution of the finest texture level (a power of two; each mip level halves it)."""
PAPER_REFLECTANCE = 0.85
INK_REFLECTANCE = 0.06
_MAX_LEVEL_VALUE = 65535.0


@dataclass(frozen=True)
class _PlateTexture:
    """Mip-mapped texture of the plate: per level (h, w, 2) uint16 of premultiplied reflectance and coverage."""

    levels: tuple[np.ndarray, ...]
    origin_m: np.ndarray
    """Board-frame (x, y) of the plate's outer top-left corner (m)."""
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
            A board seen from behind, or behind the camera, is not drawn.
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
    radiance = reflectance * _illumination(camera.width, camera.height, brightness, gradient, gradient_angle, vignetting)
    if blur_px > 0:
        radiance = cv2.GaussianBlur(radiance, (0, 0), blur_px)
    radiance += noise_sigma * rng.standard_normal(radiance.shape, dtype=np.float32)
    return np.clip(np.rint(radiance), 0, 255).astype(np.uint8)


def _render_plate(
    rays: RayField, texture: _PlateTexture, T_camera_board: np.ndarray
) -> tuple[np.ndarray, np.ndarray, slice, slice] | None:
    """Premultiplied reflectance and coverage (both (h, w) float32) of the plate over its pixel box.

    Returns None when the plate is not visible from the front.
    """
    R_board_camera = T_camera_board[:3, :3].T
    t_board_camera = -R_board_camera @ T_camera_board[:3, 3]
    if t_board_camera[2] >= 0:
        return None
    box = _plate_pixel_box(rays, texture, R_board_camera, t_board_camera)
    if box is None:
        return None
    rows, cols = box
    s = rays.supersample
    sub_rows, sub_cols = slice(rows.start * s, rows.stop * s), slice(cols.start * s, cols.stop * s)
    tex_u, tex_v = _texel_coordinates(
        rays.x[sub_rows, sub_cols], rays.y[sub_rows, sub_cols], texture, R_board_camera, t_board_camera
    )
    level = _mip_level(tex_u, tex_v, len(texture.levels))
    sampled = np.zeros((*tex_u.shape, 2), np.float32)
    for k in range(int(np.floor(level.min())), int(np.ceil(level.max())) + 1):
        weight = np.clip(1.0 - np.abs(level - k), 0.0, 1.0)
        scale = np.float32(0.5**k)
        map_u, map_v = (tex_u + 0.5) * scale - 0.5, (tex_v + 0.5) * scale - 0.5
        lookup = cv2.remap(texture.levels[k], map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        sampled += weight[..., None] * lookup
    h, w = rows.stop - rows.start, cols.stop - cols.start
    pixels = sampled.reshape(h, s, w, s, 2).mean(axis=(1, 3)) / _MAX_LEVEL_VALUE
    return pixels[..., 0], pixels[..., 1], rows, cols


def _board_hits(
    x: np.ndarray, y: np.ndarray, R_board_camera: np.ndarray, t_board_camera: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Board-frame (x, y) (m) where rays with normalised coordinates (x, y) meet z = 0, and which rays do.

    Arithmetic stays in the dtype of ``x`` and ``y``.
    """
    R, t = R_board_camera.tolist(), t_board_camera.tolist()
    direction = [R[i][0] * x + R[i][1] * y + R[i][2] for i in range(3)]
    hits = direction[2] > 0
    distance = np.where(hits, -t[2] / np.where(hits, direction[2], 1), 0)
    return t[0] + distance * direction[0], t[1] + distance * direction[1], hits


def _plate_pixel_box(
    rays: RayField, texture: _PlateTexture, R_board_camera: np.ndarray, t_board_camera: np.ndarray
) -> tuple[slice, slice] | None:
    """Row and column slices (px) of the image that hold the plate, found on the coarse ray nodes."""
    bx, by, hits = _board_hits(rays.node_xy[..., 0], rays.node_xy[..., 1], R_board_camera, t_board_camera)
    size_m = np.array(texture.levels[0].shape[1::-1]) / texture.texels_per_m
    inside = hits & (bx >= texture.origin_m[0]) & (by >= texture.origin_m[1])
    inside &= (bx <= texture.origin_m[0] + size_m[0]) & (by <= texture.origin_m[1] + size_m[1])
    node_rows, node_cols = np.nonzero(inside)
    if node_rows.size == 0:
        return None
    height, width = rays.x.shape[0] // rays.supersample, rays.x.shape[1] // rays.supersample
    v0 = rays.node_v[max(node_rows.min() - 1, 0)]
    v1 = rays.node_v[min(node_rows.max() + 1, len(rays.node_v) - 1)]
    u0 = rays.node_u[max(node_cols.min() - 1, 0)]
    u1 = rays.node_u[min(node_cols.max() + 1, len(rays.node_u) - 1)]
    rows = slice(int(np.clip(np.floor(v0), 0, height)), int(np.clip(np.ceil(v1) + 1, 0, height)))
    cols = slice(int(np.clip(np.floor(u0), 0, width)), int(np.clip(np.ceil(u1) + 1, 0, width)))
    if rows.start >= rows.stop or cols.start >= cols.stop:
        return None
    return rows, cols


def _texel_coordinates(
    x: np.ndarray, y: np.ndarray, texture: _PlateTexture, R_board_camera: np.ndarray, t_board_camera: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Level-0 texel coordinates (texel centres at integers, float32) of the rays' board hits.

    Rays that miss the plane get coordinates outside the texture; all are clamped to
    a band around it so the remap stays in range.
    """
    bx, by, hits = _board_hits(x, y, R_board_camera, t_board_camera)
    height, width = texture.levels[0].shape[:2]
    u = np.where(hits, (bx - texture.origin_m[0]) * texture.texels_per_m - 0.5, -8.0)
    v = np.where(hits, (by - texture.origin_m[1]) * texture.texels_per_m - 0.5, -8.0)
    return np.clip(u, -8.0, width + 8.0).astype(np.float32), np.clip(v, -8.0, height + 8.0).astype(np.float32)


def _mip_level(tex_u: np.ndarray, tex_v: np.ndarray, n_levels: int) -> np.ndarray:
    """Fractional mip level (float32) whose texel spans one sub-pixel's footprint (longer axis)."""
    du_dcol, du_drow = np.gradient(tex_u)
    dv_dcol, dv_drow = np.gradient(tex_v)
    footprint_sq = np.maximum(du_dcol**2 + dv_dcol**2, du_drow**2 + dv_drow**2)
    return np.clip(0.5 * np.log2(np.maximum(footprint_sq, 1e-12)), 0.0, n_levels - 1.0)


def _plate_texture(board: BoardSpec) -> _PlateTexture:
    """The (cached) mip-mapped texture of the plate carrying ``board``."""
    return _plate_texture_cached(str(board))


@lru_cache(maxsize=4)
def _plate_texture_cached(spec: str) -> _PlateTexture:
    board = BoardSpec.parse(spec)
    pattern = board.render(TEXELS_PER_SQUARE).astype(np.float32) / 255.0
    reflectance = INK_REFLECTANCE + (PAPER_REFLECTANCE - INK_REFLECTANCE) * pattern
    margin = int(round(PLATE_MARGIN_SQUARES * TEXELS_PER_SQUARE))
    reflectance = np.pad(reflectance, margin, constant_values=PAPER_REFLECTANCE)
    level = np.rint(np.dstack([reflectance, np.ones_like(reflectance)]) * _MAX_LEVEL_VALUE).astype(np.uint16)
    levels = [level]
    for _ in range(int(np.log2(TEXELS_PER_SQUARE))):
        level = cv2.resize(level, (level.shape[1] // 2, level.shape[0] // 2), interpolation=cv2.INTER_AREA)
        levels.append(level)
    return _PlateTexture(tuple(levels), plate_corners_m(board)[0, :2], TEXELS_PER_SQUARE / board.square_m)


def _background(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """Mid-grey reflectance (H, W) float32: multi-scale smooth blotches over a wall/floor step."""
    reflectance = np.full((height, width), rng.uniform(0.38, 0.5), np.float32)
    for cells, amplitude in ((3, 0.10), (12, 0.05), (48, 0.025)):
        coarse = rng.standard_normal((max(2, cells * height // width), cells)).astype(np.float32)
        reflectance += amplitude * cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    horizon = rng.uniform(0.2, 0.8) * height
    rows = np.arange(height, dtype=np.float32)[:, None]
    step = 1.0 / (1.0 + np.exp((horizon - rows) / 6.0))
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
