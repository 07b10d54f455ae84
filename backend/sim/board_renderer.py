"""Render printed plates, a calibration board or any other print, as a simulated camera sees them.

A plate carries a print on the plane z = 0 of its frame (x and y along the print, z into the plate, metres), so
the camera sees the print from plate z < 0. Every sub-pixel's exact ray through the distorted lens
(:mod:`backend.sim.camera_rays`) is intersected with that plane (or with the plate's bowed surface, below). The hit
point is looked up in a mip-mapped texture of the print (:class:`PlateTexture`; trilinear: the level whose texel
matches the sub-pixel's footprint, measured between the hits of neighbouring pixels), then 2x2 sub-pixels are
averaged per pixel. The plates are composited far to near over a textured background (:func:`render_plates`), lit
with a smooth gradient and vignetting, blurred and given sensor noise.

A plate may bow (:class:`PlateBow`): the print then lies on the surface ``z(x, y)`` of mrcal's two parabolas, the
flex of :class:`~backend.core.boards.BoardSpec` (``warp_m``), continued over the whole plate. A ray meets it by
fixed-point iteration from its plane hit: take ``z`` at the current hit's (x, y), move along the ray to that depth,
:data:`BOW_ITERATIONS` times. Each step multiplies the hit's error by the surface's slope times the ray's tangent to
the plate's normal, so it converges fast for the bows boards have, and slower for large bows seen at grazing angles.
Measured against the converged hit on a 0.54 x 0.36 m board turned 40 to 70 degrees from the camera (rays up to 85
degrees off its normal), four steps leave under 0.002 texel (float32's floor) for a 1 mm bow, where one step leaves
up to a texel, and under 0.03 texel for a bow of 1/200 of the board (a 1/100 one: under 0.1 texel to 60 degrees, 0.7
at 70). A fixed count keeps the cost known (each step is a few array operations per sub-pixel): rays that graze the
plate's plane off its edge converge arbitrarily slowly, and show no print anyway. The print is looked up at the
surface point's (x, y): the print's coordinates are those of the plate's plane, as the bowed board's corners keep the
flat board's (x, y) and only leave the plane in z. A flat plate (no bow) keeps the plane's homography from rays to
texels, the fast path for the many flat renders of the demo and the tests.

A calibration board (:func:`render_board_image`) is printed on a white plate that extends
:data:`PLATE_MARGIN_SQUARES` squares beyond the pattern on every side and bows by the board's ``warp_m``; the board
frame is the one of :class:`BoardSpec` (origin at the first inner corner, x along the columns, y along the rows, z
into the board).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

from backend.core.boards import BoardSpec, bow_z
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import transform_points
from backend.sim.camera_rays import RayField, ray_field

PLATE_MARGIN_SQUARES = 1.0
"""White margin of the plate around the printed pattern, in squares."""
SUPERSAMPLE = 2
"""Sub-pixels per pixel along each axis."""
TEXELS_PER_SQUARE = 256
"""Resolution of a board's print (texels per square; a power of two, so that the mip levels halve the squares)."""
COARSEST_TEXELS = 8
"""Mip-mapping stops at the last level whose shorter side still has this many texels (a board's: one per square)."""
PAPER_REFLECTANCE = 0.85
"""Fraction of light the white paper reflects (0..1)."""
INK_REFLECTANCE = 0.06
"""Fraction of light the black print reflects (0..1)."""
_TEXTURE_ONE = 65535.0
"""uint16 texture value standing for 1.0."""
BOW_ITERATIONS = 4
"""Fixed-point steps from a ray's plane hit to its hit on a bowed plate (the module's docstring gives why four)."""


@dataclass(frozen=True)
class PlateBow:
    """A plate's bow, mrcal's two parabolas (:attr:`~backend.core.boards.BoardSpec.warp_m`): the plate's surface is
    ``z = w_x 4 r_x (1 - r_x) + w_y 4 r_y (1 - r_y)`` (m, into the plate) at plate-frame ``(x, y) = r * span_m``,
    continued beyond ``r`` 0..1 over the whole plate."""

    warp_m: tuple[float, float]
    """The flex along x and y (m): z on the centre lines ``r = 0.5``."""
    span_m: tuple[float, float]
    """Plate-frame x and y (m) where ``r`` is 1 (``r`` is 0 at the origin): a board's last corner."""

    def z_m(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The surface's z (m) at plate-frame ``x`` and ``y`` (m, arrays of one shape), in their float type."""
        return bow_z(x, y, self.warp_m, self.span_m)


@dataclass(frozen=True)
class PlateTexture:
    """Mip-mapped texture of a plate's print: per level (h, w, 2) uint16 of premultiplied reflectance and coverage,
    and the bow of the plate that carries it.

    Level 0 is the print, padded with transparent texels on the right and at the bottom to a size that every
    level halves exactly; level k + 1 is level k halved.
    """

    levels: tuple[np.ndarray, ...]
    corners_m: np.ndarray
    """(4, 3) plate-frame corners of the print (m): TL, TR, BR, BL, on z = 0."""
    texels_per_m: np.ndarray
    """(2,) texels per metre of level 0 along the plate's x and y."""
    print_texels: tuple[int, int]
    """Width and height of the print in level-0 texels (without the padding)."""
    bow: PlateBow | None = None
    """The plate's bow, the print following it at its plane's (x, y); None for a flat plate."""


def plate_texture(print_image: np.ndarray, corners_m: np.ndarray) -> PlateTexture:
    """The :class:`PlateTexture` of a uint8 grayscale ``print_image`` (255 white paper, 0 black ink) that covers the
    plate-frame rectangle ``corners_m`` (4, 3) (m: TL, TR, BR, BL on z = 0, edges along x and y)."""
    height, width = print_image.shape
    halvings = max(0, int(np.log2(min(height, width) / COARSEST_TEXELS)))
    reflectance = INK_REFLECTANCE + (PAPER_REFLECTANCE - INK_REFLECTANCE) * (print_image.astype(np.float32) / 255.0)
    level = np.rint(np.dstack([reflectance, np.ones_like(reflectance)]) * _TEXTURE_ONE).astype(np.uint16)
    level = np.pad(level, ((0, -height % 2**halvings), (0, -width % 2**halvings), (0, 0)))
    levels = [level]
    for _ in range(halvings):
        level = cv2.resize(level, (level.shape[1] // 2, level.shape[0] // 2), interpolation=cv2.INTER_AREA)
        levels.append(level)
    corners_m = np.asarray(corners_m, dtype=float)
    texels_per_m = np.array([width, height]) / (corners_m[2, :2] - corners_m[0, :2])
    return PlateTexture(tuple(levels), corners_m, texels_per_m, (width, height))


def plate_corners_m(board: BoardSpec) -> np.ndarray:
    """(4, 3) board-frame corners of the plate, print plus white margin (m): TL, TR, BR, BL."""
    margin = PLATE_MARGIN_SQUARES * board.square_m
    x0, y0 = board.outer_origin_m[:2] - margin
    x1, y1 = x0 + board.size_m[0] + 2 * margin, y0 + board.size_m[1] + 2 * margin
    return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


def render_board_image(camera: CameraIntrinsics, board: BoardSpec, T_camera_board: np.ndarray,
                       rng: np.random.Generator, **lighting: Any) -> np.ndarray:
    """A uint8 grayscale (H, W) image of ``board`` (checkerboard or ChArUco, on its plate) at pose
    ``T_camera_board`` (board to optical frame, m), its plate bowed by the board's ``warp_m``: :func:`render_plates`
    of the one plate, ``lighting`` its keyword arguments (blur, noise, brightness, gradient, vignetting)."""
    texture = _board_texture(board.with_warp((0.0, 0.0)))  # the print, shared by every flex of the board
    if any(board.warp_m):
        texture = replace(texture, bow=PlateBow(board.warp_m, board.warp_span_m))
    return render_plates(camera, [(texture, T_camera_board)], rng, **lighting)


def render_plates(
    camera: CameraIntrinsics,
    plates: Sequence[tuple[PlateTexture, np.ndarray]],
    rng: np.random.Generator,
    *,
    blur_px: float = 0.7,
    noise_sigma: float = 2.0,
    brightness: float | None = None,
    gradient: float | None = None,
    vignetting: float = 0.2,
    background: bool = True,
) -> np.ndarray:
    """A uint8 grayscale (H, W) image of printed plates, each ``(texture, T_camera_plate)`` (plate to optical, m).

    The plates are drawn far to near by the camera's distance to each plate's plane (painter's order): right for
    parallel plates (markers standing off a wall) and for plates that meet along an edge (which cannot hide each
    other while the camera sees both prints). A plate seen from behind, or not wholly in front of the camera, is
    not drawn.

    Args:
        camera: the simulated camera; its distortion is rendered exactly.
        plates: each plate's texture and its pose in the camera's optical frame (m).
        rng: the only source of randomness (lighting, background, noise).
        blur_px: sigma of the Gaussian lens blur (px); 0 for none.
        noise_sigma: sigma of the additive Gaussian sensor noise (grey levels).
        brightness: grey level a perfectly white surface would have at the image
            centre; drawn from 160..230 when None.
        gradient: relative change of the illumination from the centre to the image
            corners along a random direction; drawn from 0..0.2 when None.
        vignetting: relative darkening at the image corners.
        background: a textured background behind the plates; False leaves it black.
    """
    rays = ray_field(camera, SUPERSAMPLE)
    if brightness is None:
        brightness = rng.uniform(160.0, 230.0)
    if gradient is None:
        gradient = rng.uniform(0.0, 0.2)
    gradient_angle = rng.uniform(0.0, 2 * np.pi)
    if background:
        reflectance = _background(rng, camera.width, camera.height)
    else:
        reflectance = np.zeros((camera.height, camera.width), np.float32)
    poses = [np.asarray(T_camera_plate, dtype=float) for _, T_camera_plate in plates]
    plane_distances_m = [abs(T[:3, 2] @ T[:3, 3]) for T in poses]
    for index in sorted(range(len(plates)), key=plane_distances_m.__getitem__, reverse=True):
        drawn = _render_plate(rays, plates[index][0], poses[index])
        if drawn is not None:
            premultiplied, coverage, rows, cols = drawn
            reflectance[rows, cols] = reflectance[rows, cols] * (1.0 - coverage) + premultiplied
    illumination = _illumination(camera.width, camera.height, brightness, gradient, gradient_angle, vignetting)
    radiance = reflectance * illumination
    if blur_px > 0:
        radiance = cv2.GaussianBlur(radiance, (0, 0), blur_px)
    radiance += noise_sigma * rng.standard_normal(radiance.shape, dtype=np.float32)
    return np.clip(np.rint(radiance), 0, 255).astype(np.uint8)


def _render_plate(
    rays: RayField, texture: PlateTexture, T_camera_plate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, slice, slice] | None:
    """Premultiplied reflectance and coverage (both (h, w) float32) of the plate over its pixel box.

    Returns None unless the printed side faces the camera and the whole plate is in
    front of it (z > 0 in the optical frame).
    """
    plate_camera = transform_points(T_camera_plate, texture.corners_m)
    t_plate_camera = -T_camera_plate[:3, :3].T @ T_camera_plate[:3, 3]
    if t_plate_camera[2] >= 0 or np.any(plate_camera[:, 2] <= 0):
        return None
    H_texel_ray = _texel_homography(texture, T_camera_plate)
    if texture.bow is None:
        node_texels = cv2.perspectiveTransform(rays.node_xy, H_texel_ray)
    else:
        node_texels = _bowed_texels(rays.node_xy, texture, T_camera_plate)
    box = _plate_pixel_box(rays, texture, node_texels)
    if box is None:
        return None
    rows, cols = box
    s = rays.supersample
    sub_xy = rays.xy[rows.start * s : rows.stop * s, cols.start * s : cols.stop * s]
    h, w = rows.stop - rows.start, cols.stop - cols.start
    if texture.bow is None:
        sub_texels = None  # each level's texels come from the homography
        pixel_texels = cv2.perspectiveTransform(np.ascontiguousarray(sub_xy[::s, ::s]), H_texel_ray)
    else:
        sub_texels = _bowed_texels(sub_xy, texture, T_camera_plate)
        pixel_texels = sub_texels[::s, ::s]
    level = _mip_level(pixel_texels, s, texture)
    pixels = np.zeros((h, w, 2), np.float32)
    for k in range(int(np.floor(level.min())), int(np.ceil(level.max())) + 1):
        weight = np.clip(1.0 - np.abs(level - k), 0.0, 1.0)
        used_rows, used_cols = (np.flatnonzero(np.any(weight > 0, axis=axis)) for axis in (1, 0))
        if used_rows.size == 0:
            continue
        r, c = slice(used_rows[0], used_rows[-1] + 1), slice(used_cols[0], used_cols[-1] + 1)
        # Texel centres of level k sit at level-0 coordinates (i + 0.5) * 2**k - 0.5.
        scale = 0.5**k
        sub_r, sub_c = slice(r.start * s, r.stop * s), slice(c.start * s, c.stop * s)
        if sub_texels is None:
            H_level_ray = np.array([[scale, 0, 0.5 * scale - 0.5], [0, scale, 0.5 * scale - 0.5], [0, 0, 1]])
            texel_map = cv2.perspectiveTransform(sub_xy[sub_r, sub_c], H_level_ray @ H_texel_ray)
        else:
            texel_map = sub_texels[sub_r, sub_c] * np.float32(scale) + np.float32(0.5 * scale - 0.5)
        lookup = cv2.remap(texture.levels[k], texel_map, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        box_size = (c.stop - c.start, r.stop - r.start)
        pixels[r, c] += weight[r, c, None] * cv2.resize(lookup, box_size, interpolation=cv2.INTER_AREA)
    pixels /= _TEXTURE_ONE
    return pixels[..., 0], pixels[..., 1], rows, cols


def _texel_homography(texture: PlateTexture, T_camera_plate: np.ndarray) -> np.ndarray:
    """3x3 homography from normalised image coordinates (x/z, y/z) to level-0 texel coordinates.

    Texel centres are at integer coordinates. Rays meeting the plate's plane behind the
    camera map to points that are not on the plate, as long as the plate is wholly
    in front of the camera.
    """
    R_plate_camera = T_camera_plate[:3, :3].T
    t_plate_camera = -R_plate_camera @ T_camera_plate[:3, 3]
    # A ray d meets z = 0 at t + lambda * R d with lambda = -t_z / (R d)_z, so the hit
    # point is ((t_x R_z - t_z R_x) d, (t_y R_z - t_z R_y) d) / (R_z d).
    r_x, r_y, r_z = R_plate_camera
    t_x, t_y, t_z = t_plate_camera
    H_plate_ray = np.array([t_x * r_z - t_z * r_x, t_y * r_z - t_z * r_y, r_z])
    # Texel (0, 0) is centred half a texel inside the print's top-left corner (x0, y0).
    texel_x, texel_y = texture.texels_per_m
    x0, y0 = texture.corners_m[0, :2]
    H_texel_plate = np.array([[texel_x, 0, -0.5 - x0 * texel_x], [0, texel_y, -0.5 - y0 * texel_y], [0, 0, 1]])
    return H_texel_plate @ H_plate_ray


def _bowed_texels(xy: np.ndarray, texture: PlateTexture, T_camera_plate: np.ndarray) -> np.ndarray:
    """Level-0 texel coordinates (..., 2) where the rays of normalised image coordinates ``xy`` (..., 2) meet the
    bowed plate (``texture.bow``), in ``xy``'s float type: :data:`BOW_ITERATIONS` fixed-point steps from the plane
    hit (the module's docstring). The surface's z is taken at the hit clamped into the plate: the same surface on the
    plate, and a bounded one beyond it, where the parabolas would throw the iterates of rays that pass far off the
    plate (near its plane's horizon) to infinity. As for the plane, a ray that meets the surface behind the camera
    gives a point the plate's pixel box leaves out."""
    R_plate_camera = T_camera_plate[:3, :3].T
    t_x, t_y, t_z = (float(v) for v in -R_plate_camera @ T_camera_plate[:3, 3])
    # The ray d = (x, y, 1) runs from the camera at t in the plate's frame along R d: its point at depth z is
    # t + lambda R d with lambda = (z - t_z) / (R d)_z. Python floats keep the arrays in xy's float type.
    d_x, d_y, d_z = (float(r[0]) * xy[..., 0] + float(r[1]) * xy[..., 1] + float(r[2]) for r in R_plate_camera)
    per_depth = 1.0 / d_z
    along = -t_z * per_depth  # the plane hit's lambda
    (x0, y0), (x1, y1) = texture.corners_m[0, :2].tolist(), texture.corners_m[2, :2].tolist()
    for _ in range(BOW_ITERATIONS):
        z = texture.bow.z_m(np.clip(t_x + along * d_x, x0, x1), np.clip(t_y + along * d_y, y0, y1))
        along = (z - t_z) * per_depth
    # Texel (0, 0) is centred half a texel inside the print's top-left corner, as in _texel_homography.
    texels_x, texels_y = texture.texels_per_m.tolist()
    return np.stack([(t_x + along * d_x - x0) * texels_x - 0.5, (t_y + along * d_y - y0) * texels_y - 0.5], axis=-1)


def _plate_pixel_box(rays: RayField, texture: PlateTexture, texel_uv: np.ndarray) -> tuple[slice, slice] | None:
    """Row and column slices (px) of the image that hold the plate, found from the level-0 texel coordinates
    ``texel_uv`` (nv, nu, 2) of the coarse ray nodes; None when they hold less than 2 x 2 pixels of it (a plate cut
    by the image's edge to a sliver is not drawn)."""
    width_tex, height_tex = texture.print_texels
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
    if rows.stop - rows.start < 2 or cols.stop - cols.start < 2:  # none, or a sliver at the image's edge
        return None
    return rows, cols


def _mip_level(texel_uv: np.ndarray, supersample: int, texture: PlateTexture) -> np.ndarray:
    """Fractional mip level (float32, per pixel) whose texel spans one sub-pixel's footprint (longer axis).

    ``texel_uv`` (h, w, 2) holds level-0 texel coordinates at pixel spacing. The
    range of levels is that of the pixels that see the plate; the other pixels
    (whose footprint may be meaningless near the horizon) are clamped into it.
    """
    d_drow, d_dcol = np.gradient(texel_uv, axis=(0, 1))
    footprint_sq = np.maximum(np.sum(d_dcol**2, axis=2), np.sum(d_drow**2, axis=2))
    level = 0.5 * np.log2(np.maximum(footprint_sq, 1e-12)) - np.log2(supersample)
    width, height = texture.print_texels
    u, v = texel_uv[..., 0], texel_uv[..., 1]
    on_plate = (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    lowest, highest = (level[on_plate].min(), level[on_plate].max()) if on_plate.any() else (0.0, 0.0)
    # Within the texture's levels: a plate magnified everywhere (texels wider than sub-pixels) uses level 0.
    return np.clip(level, *np.clip([lowest, highest], 0.0, len(texture.levels) - 1.0))


@lru_cache(maxsize=4)
def _board_texture(board: BoardSpec) -> PlateTexture:
    """The (cached) mip-mapped texture of the plate carrying ``board``: its print in the white margin."""
    margin = int(round(PLATE_MARGIN_SQUARES * TEXELS_PER_SQUARE))
    print_image = np.pad(board.render(TEXELS_PER_SQUARE), margin, constant_values=255)
    return plate_texture(print_image, plate_corners_m(board))


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
