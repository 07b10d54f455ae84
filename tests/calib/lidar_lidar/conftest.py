"""The LiDAR-to-LiDAR scene every test of the problem shares: two LiDARs on the simulated robot in the yard.

``scene`` is built once per test process; :func:`scan_pair` scans it from both LiDARs at a place of the robot
(:data:`PLACEMENTS`), :data:`T_TRUE` is the answer, :func:`perturbed` makes a start off it.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.core.transforms import from_xyz_ypr, invert, make_T

SCENE_KEYS = {"pairs", "T_target_source", "fitness", "rmse_m", "converged", "std", "deviation", "agrees"}
"""One scene's own solve, in the CLI's ``scenes`` and the record's ``diagnostics["scenes"]``."""

T_BASE_SOURCE = from_xyz_ypr(np.array([0.4, 0.2, 1.1]), np.radians([0.0, 2.0, 0.0]))
"""Source LiDAR on the simulated robot (m, rad)."""
T_BASE_TARGET = from_xyz_ypr(np.array([-0.3, -0.35, 0.9]), np.radians([100.0, 12.0, -5.0]))
"""Target LiDAR: turned 100 deg, tilted 12 deg."""
T_TRUE = invert(T_BASE_TARGET) @ T_BASE_SOURCE
"""Ground-truth T_target_source."""


@pytest.fixture(scope="session")
def scene():
    """The simulated yard both LiDARs scan, built once per test process."""
    from backend.sim.lidar_scene import LidarScene

    return LidarScene()


def scan_pair(scene, seed: int, T_world_base: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(source, target) points (m, sensor frames) of one frame: VLP-16-like scans, 1 cm range noise.
    The source's rear quarter is blocked (as by the vehicle), so the overlap is partial."""
    T_world_base = np.eye(4) if T_world_base is None else T_world_base
    source = scene.scan_3d(T_world_base @ T_BASE_SOURCE, range_noise_m=0.01, rng=2 * seed + 1)
    target = scene.scan_3d(T_world_base @ T_BASE_TARGET, range_noise_m=0.01, rng=2 * seed + 2)
    front = np.abs(np.angle(np.exp(1j * (source.azimuth_rad - np.pi)))) > np.radians(45)
    return source.points[front], target.points


def perturbed(T: np.ndarray, seed: int, trans_m: float, rot_deg: float) -> np.ndarray:
    """``T`` moved by exactly ``trans_m`` (m) and ``rot_deg`` (deg) in random directions."""
    rng = np.random.default_rng(seed)
    t = rng.normal(size=3)
    axis = rng.normal(size=3)
    rotation = Rotation.from_rotvec(np.radians(rot_deg) * axis / np.linalg.norm(axis)).as_matrix()
    return T @ make_T(rotation, trans_m * t / np.linalg.norm(t))


PLACEMENTS = [np.eye(4), from_xyz_ypr(np.array([1.0, 0.5, 0.0]), np.radians([30.0, 0, 0])),
              from_xyz_ypr(np.array([-0.5, -1.0, 0.0]), np.radians([-50.0, 0, 0]))]
"""Three places of the robot in the yard (T_world_base, m, rad)."""
