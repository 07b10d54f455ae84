"""A grayscale photograph of the simulated yard, so camera images and LiDAR scans share one geometry.

Every sub-pixel's exact ray through the distorted lens (:mod:`backend.sim.camera_rays`) is
cast into the :class:`~backend.sim.lidar_scene.LidarScene` mesh, the one the simulated
LiDARs scan. Each hit is shaded as a Lambertian surface lit by a distant sun and an ambient
sky, with an albedo per surface label (:data:`LABEL_ALBEDO`) and optionally a smooth albedo
texture fixed to the scene; sub-pixels are averaged per pixel, and lens blur and sensor noise
are added. Where two faces of the mesh meet at an angle they face the sun differently, so the
image has an edge exactly where a LiDAR sees two planes intersect: the depth-continuous edges
of targetless LiDAR-camera calibration (:mod:`backend.solvers.lidar_camera_edges`). Rays that
leave the yard (over the walls) see the sky, :data:`SKY_RADIANCE`.

The board's print has the reflectances of :mod:`backend.sim.board_renderer`, on the squares where the
LiDAR sees ink (:meth:`~backend.sim.lidar_scene.LidarScene.on_black_square`). Shadows are not cast.
"""

from __future__ import annotations

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
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


def render_scene_image(
    scene: LidarScene,
    camera: CameraIntrinsics,
    T_base_camera: np.ndarray,
    rng: np.random.Generator | int | None = None,
    *,
    supersample: int = 2,
    brightness: float = 230.0,
    texture: float = 0.08,
    blur_px: float = 0.6,
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
    T = np.asarray(T_base_camera, dtype=float)
    xy = ray_field(camera, supersample).xy.reshape(-1, 2)
    rays_camera = np.column_stack([xy, np.ones(len(xy), np.float32)])
    rays_camera /= np.sqrt(np.einsum("ij,ij->i", rays_camera, rays_camera))[:, None]
    rays_base = rays_camera @ T[:3, :3].T.astype(np.float32)
    distance_m, labels, normals = scene.cast(T[:3, 3], rays_base)
    hit = labels > 0
    # The sun's cosine on the side of each face the camera sees: how a triangle is wound says nothing of its lighting.
    normals_hit, rays_hit = normals[hit].astype(np.float32), rays_base[hit]
    sun = np.where(np.einsum("ij,ij->i", normals_hit, rays_hit) < 0, 1, -1) * (normals_hit @ SUN_DIRECTION_BASE)
    albedo = _ALBEDO_BY_LABEL[labels[hit]]
    points_base = T[:3, 3] + rays_hit * distance_m[hit, None].astype(np.float32)
    on_board = np.flatnonzero(labels[hit] == LABELS["board"])
    ink = scene.on_black_square(transform_points(invert(scene.T_base_board), points_base[on_board]))
    albedo[on_board[ink]] = INK_REFLECTANCE
    if texture > 0:
        albedo *= 1 + texture * _texture(points_base, rng)
    radiance = np.full(len(labels), SKY_RADIANCE, np.float32)
    radiance[hit] = albedo * (AMBIENT + (1 - AMBIENT) * np.clip(sun, 0, None))
    image = brightness * radiance.reshape(camera.height, supersample, camera.width, supersample).mean(axis=(1, 3))
    if blur_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur_px)
    image += noise_sigma * rng.standard_normal(image.shape, dtype=np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _texture(points_base: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A smooth texture in [-1, 1] at (N, 3) scene points (m): plane waves of random direction and phase."""
    directions = rng.standard_normal((TEXTURE_WAVES, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wave_vectors = directions * (2 * np.pi / rng.uniform(0.3, 1.5, TEXTURE_WAVES))[:, None]  # rad/m
    phases = rng.uniform(0, 2 * np.pi, TEXTURE_WAVES)
    return np.sin(points_base @ wave_vectors.T.astype(np.float32) + phases.astype(np.float32)).mean(axis=1)
