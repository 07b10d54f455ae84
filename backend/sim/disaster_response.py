"""The disaster-response robot as simulated: a FLIR Blackfly beside a Livox Avia, a wall test field, V-targets.

The rig (:func:`disaster_response_truth`): the camera (:func:`~backend.sim.marker_targets.disaster_response_camera`,
photogrammetric truth) is ``camera``; the Livox, ``livox``, sits 12 cm below it and 4 cm behind, turned by a degree
or so about each axis, as a bracket holds it. Its mounting as a tape measure gives it (:data:`MEASURED_MOUNT`) is
off by 3-5 cm and 2-3 deg.

The V-target placements (:func:`v_target_placements`) follow the paper's procedure: the target at nine positions
in front of the sensors, each at two heights, 2.5 to 6 m away. Upright V-targets all have their ridge vertical,
which leaves the LiDAR's height along the ridges undetermined (the plates fix it only across them), so the target
leans by 20-35 deg to either side, or lies on its side, at alternate placements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.camera import CameraIntrinsics
from backend.core.transforms import R_BODY_OPTICAL, invert, make_T, transform_points
from backend.core.v_target import VTarget
from backend.sim.marker_targets import disaster_response_camera, render_v_target_image, v_target_cloud

V_TARGET = "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50"
"""The paper's V-target: two 100 x 60 cm plates, here at 120 deg, six 15 cm markers a face."""
CAMERA = "camera"
LIDAR = "livox"
T_CAMERA_LIVOX_TRUE = make_T(R_BODY_OPTICAL.T @ Rotation.from_euler("xyz", [0.8, -1.1, 1.4], degrees=True).as_matrix(),
                             [0.015, 0.12, -0.04])
"""The simulator's truth: the Livox (x forward, y left, z up) in the camera's optical frame (m)."""
MEASURED_MOUNT = make_T(T_CAMERA_LIVOX_TRUE[:3, :3] @ Rotation.from_euler("xyz", [2.0, -2.5, 2.2],
                                                                         degrees=True).as_matrix(),
                        T_CAMERA_LIVOX_TRUE[:3, 3] + np.array([0.04, -0.03, 0.05]))
"""``T_camera_livox`` as tape-measured: the start of a solve (3-5 cm and 2-3 deg off the truth)."""
POSITIONS = 9
HEIGHTS_M = (-0.35, 0.45)
"""Target centre heights at each position, in the camera's y (m, up is negative: the optical y points down)."""


@dataclass(frozen=True)
class VTargetShot:
    """One placement of the V-target, as both sensors see it."""

    name: str
    image: np.ndarray
    """uint8 (H, W) camera image."""
    points_lidar: np.ndarray
    """(N, 3) the Livox cloud (m, LiDAR frame)."""
    intensity: np.ndarray
    """(N,) the Livox intensities."""
    T_camera_target: np.ndarray
    """4x4 the target's true pose in the camera's optical frame (m)."""


def disaster_response_truth() -> dict[str, np.ndarray]:
    """``T_camera_frame`` (4x4, m) of every frame of the simulated rig: the camera and the Livox."""
    return {CAMERA: np.eye(4), LIDAR: T_CAMERA_LIVOX_TRUE.copy()}


def v_target_poses(seed: int = 0) -> list[np.ndarray]:
    """``T_camera_target`` of each placement: :data:`POSITIONS` positions across the view at 2.5-6 m, each at the
    two :data:`HEIGHTS_M`, facing the camera within 25 deg, upright or leaning or lying on its side in turn."""
    rng = np.random.default_rng([seed, 1870])
    poses = []
    for position in range(POSITIONS):
        distance_m = 2.5 + 3.5 * position / (POSITIONS - 1)
        lateral_m = (position % 3 - 1) * 0.32 * distance_m + rng.uniform(-0.2, 0.2)
        for k, height_m in enumerate(HEIGHTS_M):
            roll_deg = (rng.uniform(20, 35) * rng.choice([-1, 1]), 0.0, 90.0)[(2 * position + k) % 3]
            yaw_deg = rng.uniform(-25, 25) - np.degrees(np.arctan2(lateral_m, distance_m))
            R = Rotation.from_euler("zyx", [roll_deg, yaw_deg, rng.uniform(-10, 10)], degrees=True).as_matrix()
            poses.append(make_T(R, [lateral_m, height_m * distance_m / 4, distance_m]))
    return poses


def v_target_shots(camera: CameraIntrinsics | None = None, seed: int = 0) -> list[VTargetShot]:
    """Every placement of :func:`v_target_poses` rendered: the camera's image and the Livox's cloud."""
    camera = camera or disaster_response_camera()
    target = VTarget.parse(V_TARGET)
    T_livox_camera = invert(T_CAMERA_LIVOX_TRUE)
    shots = []
    for k, T_camera_target in enumerate(v_target_poses(seed)):
        rng = np.random.default_rng([seed, k])
        image = render_v_target_image(camera, target, T_camera_target, rng)
        points, intensity = v_target_cloud(target, T_livox_camera @ T_camera_target, rng)
        shots.append(VTargetShot(f"vtarget_{k:02d}", image, points, intensity, T_camera_target))
    return shots


def target_in_view(camera: CameraIntrinsics, target: VTarget, T_camera_target: np.ndarray) -> bool:
    """Whether every marker corner of ``target`` at ``T_camera_target`` falls inside the image, 10 px in."""
    uv = camera.project(transform_points(T_camera_target, target.marker_corners.reshape(-1, 3)))
    return bool(np.all((uv >= 10) & (uv <= np.array(camera.image_size) - 11)))
