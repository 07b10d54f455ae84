"""A simulated LiDAR + IMU recording: the demo rig's top LiDAR turned about every axis in the yard, scanning at
10 Hz, with an IMU rigidly attached whose clock runs ``offset_s`` ahead (``t_imu = t_lidar + offset``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.imu import ImuSamples
from backend.core.transforms import make_T, right_jacobians
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScene

R_LIDAR_IMU = Rotation.from_euler("zyx", [-90.0, 2.0, 180.0], degrees=True).as_matrix()
"""The simulated IMU's mounting: upside down and turned a quarter, as IMUs are often fitted under a LiDAR."""


@dataclass(frozen=True)
class LidarImuRecording:
    scan_times_s: np.ndarray
    scans: list[np.ndarray]
    imu: ImuSamples
    R_lidar_imu: np.ndarray
    offset_s: float


def simulate_lidar_imu(duration_s: float = 12.0, offset_s: float = 0.015, seed: int = 0, scan_hz: float = 10.0,
                       imu_hz: float = 200.0, amplitude_rad: float = 0.3, gyro_sigma: float = 0.002
                       ) -> LidarImuRecording:
    """The recording: scans (points in the LiDAR frame, m) at ``scan_hz`` on the LiDAR's clock and the IMU's
    samples (rates with a constant bias and white noise) on its own."""
    rng = np.random.default_rng(seed)
    frequencies = rng.uniform(0.25, 0.7, size=(3, 2))
    phases = rng.uniform(0, 2 * np.pi, size=(3, 2))

    def rotation_vector(t: np.ndarray, derivative: int) -> np.ndarray:
        omega = 2 * np.pi * frequencies
        angle = omega[None] * t[:, None, None] + phases[None]
        wave = (np.sin(angle) if derivative == 0 else np.cos(angle) * omega[None])
        return amplitude_rad / 2 * wave.sum(axis=2)

    T_base_lidar0 = demo_rig().T_root_frame("lidar_top")
    scene = LidarScene(include_board=False)
    scan_times = np.arange(0.0, duration_s, 1.0 / scan_hz)
    scans = []
    for k, phi in enumerate(rotation_vector(scan_times, 0)):
        T_base_lidar = T_base_lidar0 @ make_T(Rotation.from_rotvec(phi).as_matrix(), np.zeros(3))
        scans.append(scene.scan_3d(T_base_lidar, azimuth_step_deg=0.4, range_noise_m=0.01, rng=k).points)
    t_imu = np.arange(-0.3, duration_s + 0.3, 1.0 / imu_hz)
    lidar_rates = np.einsum("nij,nj->ni", right_jacobians(rotation_vector(t_imu, 0)), rotation_vector(t_imu, 1))
    gyro = lidar_rates @ R_LIDAR_IMU + np.array([0.004, -0.006, 0.003]) + rng.normal(0, gyro_sigma, lidar_rates.shape)
    imu = ImuSamples(t_imu + offset_s, gyro, np.tile([0.0, 0.0, 9.80665], (len(t_imu), 1)))
    return LidarImuRecording(scan_times, scans, imu, R_LIDAR_IMU, offset_s)
