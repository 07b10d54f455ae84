"""A grayscale photograph of the simulated yard, so camera images and LiDAR scans share one geometry.

Every sub-pixel's exact ray through the distorted lens (:mod:`backend.sim.camera_rays`) is
cast into the :class:`~backend.sim.lidar_scene.LidarScene` mesh, the one the simulated
LiDARs scan. Each hit is shaded as a Lambertian surface lit by a distant sun and an ambient
sky, with an albedo per surface label (:data:`LABEL_ALBEDO`) and optionally a smooth albedo
texture fixed to the scene; sub-pixels are averaged per pixel, and lens blur and sensor noise
are added. Where two faces of the mesh meet at an angle they face the sun differently, so the
image has an edge exactly where a LiDAR sees two planes intersect: the depth-continuous edges
of targetless LiDAR-camera calibration (:mod:`backend.calib.lidar_camera.edges`). Rays that
leave the yard (over the walls) see the sky, :data:`SKY_RADIANCE`.

The board's print has the reflectances of :mod:`backend.sim.board_renderer`, on the squares where the
LiDAR sees ink (:meth:`~backend.sim.lidar_scene.LidarScene.on_black_square`). Shadows are not cast.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from functools import lru_cache

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import CameraKey, camera_from_key, camera_key
from backend.core.transforms import invert, transform_points
from backend.sim.board_renderer import INK_REFLECTANCE, PAPER_REFLECTANCE
from backend.sim.camera_rays import ray_field
from backend.sim.lidar_scene import LABELS, LidarScene

LABEL_ALBEDO: dict[str, float] = {"floor": 0.35, "wall": 0.75, "box": 0.55, "pole": 0.85, "ramp": 0.45,
                                  "board": PAPER_REFLECTANCE, "stand": 0.3}
"""Fraction of light each kind of surface reflects (0..1), by :data:`~backend.sim.lidar_scene.LABELS` name."""
_ALBEDO_BY_LABEL = np.array([0.0, *(LABEL_ALBEDO[name] for name in sorted(LABELS, key=LABELS.get))], np.float32)

SUN_DIRECTION_BASE = (np.array([-0.8, 0.1, 0.6]) / np.linalg.norm([-0.8, 0.1, 0.6])).astype(np.float32)
"""Unit vector towards the sun in the scene's base_link frame (x forward, y left, z up): behind the robot at the
origin and above it, so the faces turned towards the robot are lit and their sides are not, and the floor is
lit differently from both: two faces of a box the camera sees differ by a quarter of the white level or more."""
AMBIENT = 0.25
"""Share of a surface's radiance that comes from the sky whatever its orientation (0..1)."""
SKY_RADIANCE = 0.95
"""Radiance of the sky as a fraction of a white surface's facing the sun."""
TEXTURE_WAVES = 4
"""Plane waves summed into the albedo texture."""
BRIGHTNESS = 230.0
"""Grey level of a white surface facing the sun."""
TEXTURE = 0.08
"""Relative amplitude of the smooth albedo texture."""
BLUR_PX = 0.6
"""Sigma of the Gaussian lens blur (px)."""
YARD_CACHE_IMAGES = 36
"""Photographs :func:`clean_yard_image` keeps (uint8, 0.9 MB each at 1280x720): the demo's 12 board poses in the
yard seen by its three cameras."""

_yard_cache: OrderedDict[tuple, np.ndarray] = OrderedDict()
_yard_lock = threading.Lock()


def clean_yard_image(T_base_board: np.ndarray, board: str, camera: CameraIntrinsics, T_base_camera: np.ndarray,
                     seed: int) -> np.ndarray:
    """The noise-free uint8 (H, W) photograph of the yard with the board at ``T_base_board`` (4x4, m, in the yard's
    frame: base_link of the robot at place 0 of :data:`~backend.sim.lidar_scene.ROBOT_PLACES`) by ``camera`` at
    ``T_base_camera`` (in the same frame), its texture seeded by ``seed``: :func:`render_scene_image` with one ray
    per pixel and no sensor noise.

    Rendered fast and shared: the yard without the board is cast and shaded once per camera
    (:func:`_yard_without_board`); per board pose only the rays that meet the board or its post nearer than the
    yard are replaced, which is what the whole scene's nearest hit is, and every photograph is kept, read-only,
    for every simulated camera of the process (the :data:`YARD_CACHE_IMAGES` most recently used).
    """
    T_board, T_camera = np.asarray(T_base_board, float), np.asarray(T_base_camera, float)
    key = (T_board.tobytes(), board, camera_key(camera), T_camera.tobytes(), seed)
    with _yard_lock:
        image = _yard_cache.get(key)
        if image is not None:
            _yard_cache.move_to_end(key)
            return image
    origin, rays_base, yard_distance_m, yard_radiance = _yard_without_board(key[2], key[3], seed)
    board_only = LidarScene(T_board, board=board, include_yard=False)
    # Only rays inside the cone around the board's (and post's) bounding sphere can meet them.
    centre = board_only.vertices.mean(axis=0)
    radius_m, range_m = np.linalg.norm(board_only.vertices - centre, axis=1).max(), np.linalg.norm(centre - origin)
    candidates = np.arange(len(rays_base))
    if range_m > radius_m:
        cos_cone = np.sqrt(1 - (radius_m / range_m) ** 2)
        candidates = np.flatnonzero(rays_base @ ((centre - origin) / range_m).astype(np.float32) >= cos_cone)
    distance_m, labels, normals = board_only.cast(origin, rays_base[candidates])
    nearer = distance_m < yard_distance_m[candidates]
    radiance = yard_radiance.copy()
    radiance[candidates[nearer]] = _radiance(board_only, origin, rays_base[candidates[nearer]], distance_m[nearer],
                                             labels[nearer], normals[nearer],
                                             _texture_waves(np.random.default_rng(seed)), TEXTURE)
    image = _develop(radiance, camera, 1, BRIGHTNESS, BLUR_PX, 0.0, np.random.default_rng())
    image.setflags(write=False)
    with _yard_lock:
        _yard_cache[key] = image
        while len(_yard_cache) > YARD_CACHE_IMAGES:
            _yard_cache.popitem(last=False)
    return image


@lru_cache(maxsize=4)
def _yard_without_board(camera: CameraKey, T_base_camera: bytes, seed: int
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The camera's centre and rays (:func:`_camera_rays`, one per pixel, base_link) and per ray the distance
    (m, float32, ``inf`` for the sky) to the yard without the board and the radiance seen there (:func:`_radiance`).
    """
    intrinsics, T = camera_from_key(camera), np.frombuffer(T_base_camera).reshape(4, 4)
    origin, rays_base = _camera_rays(intrinsics, T, 1)
    yard = LidarScene(include_board=False)
    distance_m, labels, normals = yard.cast(origin, rays_base)
    radiance = _radiance(yard, origin, rays_base, distance_m, labels, normals,
                         _texture_waves(np.random.default_rng(seed)), TEXTURE)
    for array in (rays_base, radiance):
        array.setflags(write=False)
    return origin, rays_base, distance_m.astype(np.float32), radiance


def render_scene_image(
    scene: LidarScene,
    camera: CameraIntrinsics,
    T_base_camera: np.ndarray,
    rng: np.random.Generator | int | None = None,
    *,
    supersample: int = 2,
    brightness: float = BRIGHTNESS,
    texture: float = TEXTURE,
    blur_px: float = BLUR_PX,
    noise_sigma: float = 1.5,
) -> np.ndarray:
    """A uint8 (H, W) grayscale image of ``scene`` by ``camera`` (exact distortion) posed at ``T_base_camera``.

    Args:
        scene: the yard and board as the simulated LiDARs see them (base_link frame, m).
        camera: the simulated camera's true intrinsics.
        T_base_camera: 4x4 pose of the camera's optical frame in the scene's base_link frame (m).
        rng: the source of randomness (texture phases, sensor noise), or a seed.
        supersample: rays per pixel along each axis, averaged (anti-aliasing: edges land to a fraction
            of a pixel, as on a real sensor).
        brightness: grey level of a white surface facing the sun.
        texture: relative amplitude of the smooth albedo texture (0 for none); its waves are 0.3 to
            1.5 m long, fixed to the scene, too gentle to make edges of their own.
        blur_px: sigma of the Gaussian lens blur (px); 0 for none.
        noise_sigma: sigma of the additive Gaussian sensor noise (grey levels).
    """
    rng = np.random.default_rng(rng)
    origin, rays_base = _camera_rays(camera, T_base_camera, supersample)
    waves = _texture_waves(rng) if texture > 0 else None
    distance_m, labels, normals = scene.cast(origin, rays_base)
    radiance = _radiance(scene, origin, rays_base, distance_m, labels, normals, waves, texture)
    return _develop(radiance, camera, supersample, brightness, blur_px, noise_sigma, rng)


def _camera_rays(camera: CameraIntrinsics, T_base_camera: np.ndarray, supersample: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The camera's centre (3,) and the unit directions (N, 3) float32 of its sub-pixel rays, in base_link (m)."""
    T = np.asarray(T_base_camera, dtype=float)
    xy = ray_field(camera, supersample).xy.reshape(-1, 2)
    rays_camera = np.column_stack([xy, np.ones(len(xy), np.float32)])
    rays_camera /= np.sqrt(np.einsum("ij,ij->i", rays_camera, rays_camera))[:, None]
    return T[:3, 3], rays_camera @ T[:3, :3].T.astype(np.float32)


def _radiance(scene: LidarScene, origin: np.ndarray, rays_base: np.ndarray, distance_m: np.ndarray,
              labels: np.ndarray, normals: np.ndarray, waves: tuple[np.ndarray, np.ndarray] | None,
              texture: float) -> np.ndarray:
    """Float32 radiance (fraction of a white surface facing the sun) along each ray, from its hit in ``scene``
    (``distance_m``, ``labels``, ``normals`` as :meth:`LidarScene.cast` returns them; label 0 sees the sky)."""
    hit = labels > 0
    # The sun's cosine on the side of each face the camera sees: how a triangle is wound says nothing of its lighting.
    normals_hit, rays_hit = normals[hit].astype(np.float32), rays_base[hit]
    sun = np.where(np.einsum("ij,ij->i", normals_hit, rays_hit) < 0, 1, -1) * (normals_hit @ SUN_DIRECTION_BASE)
    albedo = _ALBEDO_BY_LABEL[labels[hit]]
    points_base = origin + rays_hit * distance_m[hit, None].astype(np.float32)
    on_board = np.flatnonzero(labels[hit] == LABELS["board"])
    ink = scene.on_black_square(transform_points(invert(scene.T_base_board), points_base[on_board]))
    albedo[on_board[ink]] = INK_REFLECTANCE
    if waves is not None:
        albedo *= 1 + texture * _texture(points_base, waves)
    radiance = np.full(len(labels), SKY_RADIANCE, np.float32)
    radiance[hit] = albedo * (AMBIENT + (1 - AMBIENT) * np.clip(sun, 0, None))
    return radiance


def _develop(radiance: np.ndarray, camera: CameraIntrinsics, supersample: int, brightness: float, blur_px: float,
             noise_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """The uint8 (H, W) image of per-sub-pixel ``radiance``: averaged per pixel, blurred, with sensor noise."""
    image = brightness * radiance.reshape(camera.height, supersample, camera.width, supersample).mean(axis=(1, 3))
    if blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_px)
    if noise_sigma > 0:
        image += noise_sigma * rng.standard_normal(image.shape, dtype=np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _texture_waves(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The texture's plane waves: wave vectors (TEXTURE_WAVES, 3) float32 (rad/m) of random direction and length
    0.3 to 1.5 m, and their phases (TEXTURE_WAVES,) float32 (rad)."""
    directions = rng.standard_normal((TEXTURE_WAVES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wave_vectors = directions * (2 * np.pi / rng.uniform(0.3, 1.5, TEXTURE_WAVES))[:, None]  # rad/m
    phases = rng.uniform(0, 2 * np.pi, TEXTURE_WAVES)
    return wave_vectors.astype(np.float32), phases.astype(np.float32)


def _texture(points_base: np.ndarray, waves: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A smooth texture in [-1, 1] at (N, 3) scene points (m): the mean of ``waves`` (:func:`_texture_waves`)."""
    wave_vectors, phases = waves
    return np.sin(points_base @ wave_vectors.T + phases).mean(axis=1)
