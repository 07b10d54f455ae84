"""A simulated LiDAR + IMU recording: the demo rig's top LiDAR turned about every axis in the yard, scanning at
10 Hz, with an IMU rigidly attached whose clock runs ``offset_s`` ahead (``t_imu = t_lidar + offset``). The turning
rig's scans serve two LiDARs on their own clocks too (:func:`turning_scans`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.imu import ImuSamples
from backend.core.transforms import make_T, right_jacobians
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScene

R_LIDAR_IMU = Rotation.from_euler("zyx", [-90.0, 2.0, 180.0], degrees=True).as_matrix()
"""The simulated IMU's mounting: upside down and turned a quarter, as IMUs are often fitted under a LiDAR."""
T_LIDAR_IMU_M = np.array([0.06, -0.04, -0.09])
"""Where the simulated IMU sits in the LiDAR's frame (m): under it and to one side."""
GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class LidarImuRecording:
    scan_times_s: np.ndarray
    scans: list[np.ndarray]
    imu: ImuSamples
    R_lidar_imu: np.ndarray
    offset_s: float
    t_lidar_imu_m: np.ndarray
    """The IMU's position in the LiDAR's frame (m)."""


def turning(seed: int, amplitude_rad: float) -> Callable[[np.ndarray, int], np.ndarray]:
    """The rig's turn as a rotation vector (rad) over time (s), or its time derivative (``derivative`` 1): a sum of
    two sines of 0.25-0.7 Hz about each axis."""
    rng = np.random.default_rng(seed)
    frequencies = rng.uniform(0.25, 0.7, size=(3, 2))
    phases = rng.uniform(0, 2 * np.pi, size=(3, 2))

    def rotation_vector(t: np.ndarray, derivative: int) -> np.ndarray:
        omega = 2 * np.pi * frequencies
        angle = omega[None] * t[:, None, None] + phases[None]
        wave = (np.sin(angle) if derivative == 0 else np.cos(angle) * omega[None])
        return amplitude_rad / 2 * wave.sum(axis=2)

    return rotation_vector


def turning_scans(sensor: str, times_s: np.ndarray, rotation_vector: Callable[[np.ndarray, int], np.ndarray],
                  scene: LidarScene, pivot: str = "lidar_top") -> list[np.ndarray]:
    """Scans (points in ``sensor``'s frame, m) of the demo rig's 3D LiDAR ``sensor`` at true times ``times_s`` while
    the rig turns about ``pivot``'s origin by ``rotation_vector``."""
    rig = demo_rig()
    T_base_pivot0, T_pivot_sensor = rig.T_root_frame(pivot), rig.T_a_b(pivot, sensor)
    scans = []
    for k, phi in enumerate(rotation_vector(np.asarray(times_s, float), 0)):
        T_base_sensor = T_base_pivot0 @ make_T(Rotation.from_rotvec(phi).as_matrix(), np.zeros(3)) @ T_pivot_sensor
        scans.append(scene.scan_3d(T_base_sensor, azimuth_step_deg=0.4, range_noise_m=0.01, rng=k).points)
    return scans


def simulate_lidar_imu(duration_s: float = 12.0, offset_s: float = 0.015, seed: int = 0, scan_hz: float = 10.0,
                       imu_hz: float = 200.0, amplitude_rad: float = 0.3, gyro_sigma: float = 0.002,
                       accel_sigma: float = 0.03) -> LidarImuRecording:
    """The recording: scans (points in the LiDAR frame, m) at ``scan_hz`` on the LiDAR's clock and the IMU's
    samples on its own (angular rates; specific forces from the lever arm :data:`T_LIDAR_IMU_M` and gravity; each
    with a constant bias and white noise)."""
    rng = np.random.default_rng(seed)
    rotation_vector = turning(seed, amplitude_rad)
    scan_times = np.arange(0.0, duration_s, 1.0 / scan_hz)
    scans = turning_scans("lidar_top", scan_times, rotation_vector, LidarScene(include_board=False))
    t_imu = np.arange(-0.3, duration_s + 0.3, 1.0 / imu_hz)
    phi = rotation_vector(t_imu, 0)
    lidar_rates = np.einsum("nij,nj->ni", right_jacobians(phi), rotation_vector(t_imu, 1))
    lidar_angular_accel = np.gradient(lidar_rates, t_imu, axis=0)
    # the LiDAR turns about its own origin, so the IMU's acceleration is the lever arm's: alpha x r + w x (w x r),
    # in the LiDAR's axes; its specific force adds gravity's reaction
    lever_accel = (np.cross(lidar_angular_accel, T_LIDAR_IMU_M)
                   + np.cross(lidar_rates, np.cross(lidar_rates, T_LIDAR_IMU_M)))
    R_world_lidar = demo_rig().T_root_frame("lidar_top")[:3, :3] @ Rotation.from_rotvec(phi).as_matrix()
    gravity_lidar = np.einsum("nji,j->ni", R_world_lidar, [0.0, 0.0, -GRAVITY_M_S2])
    force = (lever_accel - gravity_lidar) @ R_LIDAR_IMU  # into the IMU's axes
    gyro = lidar_rates @ R_LIDAR_IMU + np.array([0.004, -0.006, 0.003]) + rng.normal(0, gyro_sigma, lidar_rates.shape)
    accel = force + np.array([0.05, -0.03, 0.08]) + rng.normal(0, accel_sigma, force.shape)
    imu = ImuSamples(t_imu + offset_s, gyro, accel)
    return LidarImuRecording(scan_times, scans, imu, R_LIDAR_IMU, offset_s, T_LIDAR_IMU_M)
