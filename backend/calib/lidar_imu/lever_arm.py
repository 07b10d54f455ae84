"""The IMU's position in the LiDAR's frame (the lever arm), from the accelerometer, once the rotation and the time
offset are known.

With the rotation ``R_lidar_imu`` and the offset fixed, every accelerometer sample is linear in the unknowns: the
lever arm ``r`` (m, LiDAR frame), gravity in the first scan's frame ``g`` (m/s²) and the accelerometer's bias ``b``
(m/s², IMU frame)::

    f = R_imu_lidar (R_lidar_world (a_lidar - g) + (alpha x r + omega x (omega x r))) + b

where ``a_lidar`` is the LiDAR's own acceleration (the second derivative of a smoothing spline through its odometry
positions) and ``omega``, ``alpha``, ``R_lidar_world`` its angular rate, angular acceleration and orientation, which
come from the gyro (far less noisy than odometry at 10 Hz: 0.2 deg of odometry drift puts 0.03 m/s² of gravity in
the wrong axis): its bias-corrected rates turned into the LiDAR's axes, a smoothing spline's derivative of them, and
their integral from the first sample (the "world" frame gravity is solved in). One least-squares
solve gives all nine; a linear model needs no start and cannot fall into a wrong minimum.

The lever arm is seen only through the rotation's ``alpha x r + omega x (omega x r)``: a rig that hardly turned, or
turned about one axis only, leaves a component of ``r`` undetermined. Its sigma (the solve's covariance, widened by
how much the residuals persist from sample to sample) then exceeds :data:`MAX_LEVER_ARM_STD_M`, and the result says
the translation is not determined instead of returning a number. The gravity's magnitude, which the solve does not
know, is the cross-check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.spline import UniformSpline
from backend.calib.time_offset.alignment import persistence
from backend.core.imu import ImuSamples
from backend.core.transforms import skew

KNOTS_PER_S = 2.0
"""Knots per second of the smoothing splines through the odometry and the gyro: a hand-turned rig moves below
1 Hz, and a second derivative of 10 Hz odometry needs heavy smoothing."""
MAX_LEVER_ARM_STD_M = 0.02
"""Largest 1-sigma (m, along the worst direction) for the lever arm to count as determined by the motion."""
GRAVITY_M_S2 = 9.80665
EDGE_S = 0.5
"""IMU samples this close (s) to the scans' first or last are left out: the splines are poorly held at their ends."""


@dataclass(frozen=True)
class LeverArm:
    """The lever arm's solve."""

    t_lidar_imu_m: np.ndarray
    """(3,) the IMU's origin in the LiDAR's frame (m); NaN when not determined."""
    covariance: np.ndarray
    """3x3 covariance of ``t_lidar_imu_m`` (m²); NaN when not determined."""
    determined: bool
    worst_std_m: float
    """1-sigma (m) along the least determined direction."""
    gravity_m_s2: float
    """The solved gravity's magnitude (m/s²), against :data:`GRAVITY_M_S2` as the cross-check."""
    gravity_std_m_s2: float
    accel_bias_m_s2: np.ndarray
    residual_m_s2: float
    """RMS of the accelerometer less the model (m/s²)."""
    samples: int

    def to_dict(self) -> dict:
        return {"t_lidar_imu_m": self.t_lidar_imu_m.tolist(), "determined": self.determined,
                "worst_std_m": self.worst_std_m, "gravity_m_s2": self.gravity_m_s2,
                "gravity_std_m_s2": self.gravity_std_m_s2, "accel_bias_m_s2": self.accel_bias_m_s2.tolist(),
                "residual_m_s2": self.residual_m_s2, "samples": self.samples}


def _smooth(times_s: np.ndarray, values: np.ndarray, at_s: np.ndarray, derivative: int = 0) -> np.ndarray:
    """A smoothing spline (:data:`KNOTS_PER_S`) through ``values`` (N, 3) at ``times_s``, evaluated (or its
    ``derivative``) at ``at_s``."""
    spline = UniformSpline(float(times_s[0]), float(times_s[-1]), 1.0 / KNOTS_PER_S)
    return spline.basis(at_s, derivative) @ spline.fit(times_s, values)


def _integrated(t_s: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Orientations ``R_world_lidar`` (N, 3, 3) at ``t_s`` from angular rates (N, 3; rad/s, the LiDAR's axes) by
    integration from the first sample (the world frame)."""
    steps = Rotation.from_rotvec(0.5 * (omega[:-1] + omega[1:]) * np.diff(t_s)[:, None]).as_matrix()
    orientations = np.empty((len(t_s), 3, 3))
    orientations[0] = np.eye(3)
    for k, step in enumerate(steps):
        orientations[k + 1] = orientations[k] @ step
    return orientations


def solve_lever_arm(scan_t_s: np.ndarray, T_first_scan: np.ndarray, imu: ImuSamples, offset_s: float,
                    R_lidar_imu: np.ndarray, gyro_bias_rad_s: np.ndarray) -> LeverArm:
    """The lever arm, gravity and the accelerometer's bias from the LiDAR's odometry poses (K, 4, 4) at
    ``scan_t_s`` (s, the LiDAR's clock; their positions give the LiDAR's own acceleration) and the IMU's samples
    (``t_imu = t_lidar + offset_s``; the gyro's, less ``gyro_bias_rad_s``, give the rotation)."""
    t_lidar = imu.t_s - offset_s
    inside = (t_lidar >= scan_t_s[0] + EDGE_S) & (t_lidar <= scan_t_s[-1] - EDGE_S)
    t = t_lidar[inside]
    force_imu = imu.accel_m_s2[inside]
    rates_lidar = (imu.gyro_rad_s - gyro_bias_rad_s) @ R_lidar_imu.T  # the gyro's rates in the LiDAR's axes
    omega = _smooth(t_lidar, rates_lidar, t)
    alpha = _smooth(t_lidar, rates_lidar, t, derivative=1)
    accel_lidar = _smooth(scan_t_s, T_first_scan[:, :3, 3], t, derivative=2)
    R_lidar_world = np.transpose(_integrated(t, omega), (0, 2, 1))
    R_imu_lidar = R_lidar_imu.T
    n = len(t)
    # rows: f - R_il R_lw a_l = [-R_il R_lw | R_il (skew(alpha) + skew(omega)^2) | I] [g, r, b]
    design = np.zeros((n, 3, 9))
    design[:, :, 0:3] = -R_imu_lidar @ R_lidar_world
    rotation_terms = skew(alpha) + skew(omega) @ skew(omega)
    design[:, :, 3:6] = R_imu_lidar @ rotation_terms
    design[:, :, 6:9] = np.eye(3)
    target = force_imu - np.einsum("ij,njk,nk->ni", R_imu_lidar, R_lidar_world, accel_lidar)
    A, y = design.reshape(3 * n, 9), target.reshape(3 * n)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    residuals = (y - A @ x).reshape(n, 3)
    variance = float(np.sum(residuals**2)) / max(3 * n - 9, 1) * persistence(residuals)
    covariance = variance * np.linalg.pinv(A.T @ A)
    gravity, lever, bias = x[0:3], x[3:6], x[6:9]
    lever_covariance = covariance[3:6, 3:6]
    worst = float(np.sqrt(max(np.linalg.eigvalsh(lever_covariance).max(), 0.0)))
    determined = worst <= MAX_LEVER_ARM_STD_M
    gravity_norm = float(np.linalg.norm(gravity))
    gravity_std = float(np.sqrt(max(gravity @ covariance[0:3, 0:3] @ gravity, 0.0)) / max(gravity_norm, 1e-12))
    return LeverArm(lever if determined else np.full(3, np.nan),
                    lever_covariance if determined else np.full((3, 3), np.nan), determined, worst, gravity_norm,
                    gravity_std, bias, float(np.sqrt(np.mean(residuals**2))), n)

