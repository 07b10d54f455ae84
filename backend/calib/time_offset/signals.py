"""What each sensor gives as its motion over time, for lining two sensors' clocks up.

A *signal* is a sequence of 3-vectors on one sensor's clock, of one of three kinds, each related between the two
sensors by a constant rotation (their mounting) alone, so no extrinsic is needed to compare them (but for
``"lines"``, which needs the rig's current one to put the camera's signal in the scanner's plane):

- ``"directions"``: the unit normal of a board both sensors see, in the sensor's frame, turned towards the sensor.
  A camera reads it from the board's pose, a LiDAR from the plane fitted to the board's points; a board carried
  through both views gives both sensors the same normal up to their mounting rotation.
- ``"rates"``: angular rates (rad/s). A gyro measures them; a camera (from the board poses) or a LiDAR (from its
  odometry) gives them as finite differences of its orientations. Two sensors on one rig turned in a static scene,
  or two cameras watching one board, see the same angular velocity up to their mounting rotation.
- ``"lines"``: the unit direction (z = 0) along which a board cuts a 2D scanner's plane, in the scanner's frame.
  The scanner reads it from the board's segment in its scan, a camera from the board's normal rotated into the
  scanner's frame by ``T_camera_lidar`` (:mod:`.scan_line`); the two agree up to a turn about the scan plane's
  normal (the error of ``T_camera_lidar``'s yaw). One angle a sample: only turning the board about the vertical
  moves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from backend.calib.camera_imu.time_offset import rates_from_rotations
from backend.core.errors import InputError
from backend.core.imu import ImuSamples

SignalKind = Literal["directions", "rates", "lines"]
MIN_SAMPLES = 20
"""Fewest samples of a signal worth aligning."""


@dataclass(frozen=True)
class MotionSignal:
    """One sensor's motion, sample by sample, on its own clock."""

    sensor: str
    kind: SignalKind
    t_s: np.ndarray
    """(N,) increasing sample times (s, the sensor's clock)."""
    vectors: np.ndarray
    """(N, 3) unit board normals (``directions``), angular rates (rad/s, ``rates``) in the sensor's frame, or unit
    directions of the board's cut through a 2D scanner's plane (``lines``, z = 0, the scanner's frame)."""

    def __post_init__(self) -> None:
        if len(self.t_s) < MIN_SAMPLES:
            raise InputError(f"{self.sensor}: {len(self.t_s)} usable sample(s) of its motion; lining clocks up needs "
                             f"at least {MIN_SAMPLES}", self.sensor)
        if np.any(np.diff(self.t_s) <= 0):
            raise InputError(f"{self.sensor}: its sample times do not increase", self.sensor)

    def between(self, start_s: float, end_s: float) -> MotionSignal:
        """The samples within ``start_s`` .. ``end_s`` (s, inclusive)."""
        inside = (self.t_s >= start_s) & (self.t_s <= end_s)
        return MotionSignal(self.sensor, self.kind, self.t_s[inside], self.vectors[inside])


def facing_normals(normals: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Unit plane normals (N, 3) flipped where needed to point back at the sensor from a point of each plane
    (N, 3, sensor frame, m), so both sensors' normals of one board agree in sign."""
    unit = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(np.sum(unit * points, axis=1, keepdims=True) > 0, -unit, unit)


def board_normal_signal(sensor: str, t_s: np.ndarray, T_sensor_board: np.ndarray) -> MotionSignal:
    """The board's normal (its z axis, facing the sensor) from its poses (K, 4, 4) at ``t_s`` (s)."""
    order = np.argsort(t_s)
    T = np.asarray(T_sensor_board, float)[order]
    return MotionSignal(sensor, "directions", np.asarray(t_s, float)[order], facing_normals(T[:, :3, 2], T[:, :3, 3]))


def orientation_rate_signal(sensor: str, t_s: np.ndarray, R_world_sensor: np.ndarray) -> MotionSignal:
    """Angular rates (rad/s, the moving frame's axes) between consecutive orientations (K, 3, 3) at ``t_s`` (s);
    pairs further apart than 2.5 median steps (a gap, a missed board) are skipped."""
    order = np.argsort(t_s)
    t = np.asarray(t_s, float)[order]
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    times, rates = rates_from_rotations(t, np.asarray(R_world_sensor, float)[order], 2.5 * step)
    return MotionSignal(sensor, "rates", times, rates)


def gyro_signal(sensor: str, imu: ImuSamples) -> MotionSignal:
    """The gyro's angular rates (rad/s, the IMU's axes)."""
    return MotionSignal(sensor, "rates", imu.t_s, imu.gyro_rad_s)
