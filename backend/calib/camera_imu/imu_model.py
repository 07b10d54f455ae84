"""The IMU's intrinsics in a camera-IMU fit: Kalibr's ``calibrated`` and ``scale-misalignment`` IMU models.

``calibrated`` takes the IMU's axes as ideal: a gyro sample is the angular rate plus a bias, an accelerometer sample
the specific force plus a bias. ``scale-misalignment`` (Kalibr's ``IccScaledMisalignedImu``) adds what a MEMS IMU
leaves to the user when it has no factory calibration:

- accelerometer: ``a_meas = M_a f + b_a``, ``M_a`` lower-triangular (scale on the diagonal, the axes' misalignment
  below it; upper-triangular terms would only turn the frame, which ``T_cam_imu`` already does), so the IMU's frame
  is the accelerometer's;
- gyro: ``w_meas = M_g R_gyro_accel w + A R_gyro_accel f + b_g``, ``M_g`` lower-triangular, the gyro triad's own
  orientation ``R_gyro_accel`` and its sensitivity to specific force ``A`` ((rad/s) / (m/s²)).

That is 24 parameters beside the extrinsic. Kalibr's third model (``scale-misalignment-size-effect``, each
accelerometer axis at its own lever arm) is not offered: on EuRoC's recording (a trial) it moved the translation
6-8 mm further from both references while lowering the accelerometer residual by 3 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

IMU_MODELS = ("calibrated", "scale-misalignment")
"""The IMU models a fit can use (Kalibr's ``--imu-models`` names)."""
SIZE = 24
"""Parameters of the ``scale-misalignment`` model: M_a (6), M_g (6), R_gyro_accel (3), A (9)."""
ACCEL_M, GYRO_M, GYRO_ROTATION, G_SENSITIVITY = slice(0, 6), slice(6, 12), slice(12, 15), slice(15, 24)
_LOWER = np.tril_indices(3)


@dataclass(frozen=True)
class ImuIntrinsics:
    """The ``scale-misalignment`` model's parameters (identity and zero: an ideal IMU)."""

    accel_M: np.ndarray
    """3x3 lower-triangular: accelerometer scale and misalignment."""
    gyro_M: np.ndarray
    """3x3 lower-triangular: gyro scale and misalignment."""
    R_gyro_accel: np.ndarray
    """3x3 rotation of the gyro triad from the accelerometer's (the IMU's) axes."""
    g_sensitivity: np.ndarray
    """3x3 gyro sensitivity to specific force ((rad/s) / (m/s²))."""

    @classmethod
    def ideal(cls) -> ImuIntrinsics:
        return cls(np.eye(3), np.eye(3), np.eye(3), np.zeros((3, 3)))

    def stepped(self, step: np.ndarray) -> ImuIntrinsics:
        """Moved by ``step`` (:data:`SIZE`: the triangles' entries row by row, a left rotation vector of the gyro
        triad in rad, ``A`` row by row)."""
        return ImuIntrinsics(self.accel_M + _lower(step[ACCEL_M]), self.gyro_M + _lower(step[GYRO_M]),
                             Rotation.from_rotvec(step[GYRO_ROTATION]).as_matrix() @ self.R_gyro_accel,
                             self.g_sensitivity + step[G_SENSITIVITY].reshape(3, 3))

    def to_dict(self) -> dict:
        return {"model": "scale-misalignment", "accel_M": self.accel_M.tolist(), "gyro_M": self.gyro_M.tolist(),
                "R_gyro_accel": self.R_gyro_accel.tolist(), "g_sensitivity_rad_s_per_m_s2": self.g_sensitivity.tolist()}


def lower_triangle_jacobian(vectors: np.ndarray) -> np.ndarray:
    """(N, 3, 6): the derivative of ``L v`` by the lower-triangular ``L``'s entries (row by row), per vector."""
    jacobian = np.zeros((len(vectors), 3, 6))
    for column, (row, entry) in enumerate(zip(*_LOWER, strict=True)):
        jacobian[:, row, column] = vectors[:, entry]
    return jacobian


def _lower(entries: np.ndarray) -> np.ndarray:
    matrix = np.zeros((3, 3))
    matrix[_LOWER] = entries
    return matrix
