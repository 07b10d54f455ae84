"""A simulated camera + IMU recording with a board waved in front: known extrinsic, time offset and biases.

The IMU's pose in the board's frame moves along sums of sines (so its angular rate and acceleration are exact
derivatives); the camera, rigidly attached by ``T_cam_imu``, sees the AprilGrid's corners at 20 Hz on its own clock,
which runs ``offset_s`` behind the IMU's (Kalibr's ``t_imu = t_cam + offset``). Pixels, rates and specific forces
carry white noise and the IMU constant biases; the IMU's axes are ideal unless ``intrinsics`` scale and misalign
them (Kalibr's ``scale-misalignment`` model).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.imu_model import ImuIntrinsics
from backend.calib.camera_imu.observations import BoardObservations, format_detections_csv
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.imu import ImuSamples
from backend.core.transforms import invert, make_T, right_jacobians
from backend.devices.imu_csv import format_imu_csv
from backend.sim.board_renderer import render_board_image

BOARD = "aprilgrid:6x6:0.088:0.3"
CAMERA = CameraIntrinsics("pinhole-radtan", 752, 480, np.array([[458.654, 0, 367.215], [0, 457.296, 248.375],
                                                                 [0, 0, 1]]),
                          np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]))
"""EuRoC's cam0."""
T_CAM_IMU = make_T(Rotation.from_euler("zyx", [90.0, 1.5, -0.8], degrees=True).as_matrix(), [0.065, -0.021, -0.01])
"""The simulated extrinsic: an IMU turned 90 deg about the camera's axis, 7 cm beside it."""
GRAVITY_BOARD = np.array([0.0, 9.80665, 0.0])
"""Gravity in the board's frame (m/s²): the board stands upright, its y axis down."""


@dataclass(frozen=True)
class CameraImuRecording:
    camera: CameraIntrinsics
    observations: BoardObservations
    imu: ImuSamples
    T_cam_imu: np.ndarray
    offset_s: float
    gyro_bias_rad_s: np.ndarray
    accel_bias_m_s2: np.ndarray
    T_cam_board: np.ndarray
    """(K, 4, 4) the board's true pose in each frame of ``observations``."""


def simulate_recording(duration_s: float = 24.0, offset_s: float = 0.023, seed: int = 0, pixel_sigma: float = 0.3,
                       gyro_sigma: float = 0.003, accel_sigma: float = 0.03, camera_hz: float = 20.0,
                       imu_hz: float = 200.0, rotation_amplitude_rad: float = 0.35,
                       translation_amplitude_m: float = 0.15,
                       intrinsics: ImuIntrinsics | None = None) -> CameraImuRecording:
    """A recording of ``duration_s`` (camera clock from 1000 s, IMU clock ``offset_s`` ahead), the IMU measuring
    through ``intrinsics`` (None: ideal axes)."""
    rng = np.random.default_rng(seed)
    frequencies = rng.uniform(0.25, 1.1, size=(2, 3, 3))  # (rotation|translation, axis, component)
    phases = rng.uniform(0, 2 * np.pi, size=(2, 3, 3))
    amplitudes = np.array([rotation_amplitude_rad, translation_amplitude_m]) / 3
    T_board_cam0 = make_T(np.eye(3), [0.28, 0.28, -0.85])  # facing the grid's middle from 0.85 m
    T_board_imu0 = T_board_cam0 @ T_CAM_IMU

    def motion(t: np.ndarray, derivative: int) -> tuple[np.ndarray, np.ndarray]:
        """The rotation vector and the position offset (N, 3) or their time derivatives."""
        omega = 2 * np.pi * frequencies
        angle = omega[None] * t[:, None, None, None] + phases[None]
        wave = [np.sin, np.cos, lambda a: -np.sin(a)][derivative](angle) * omega[None] ** derivative
        summed = wave.sum(axis=3) * amplitudes[None, :, None]
        return summed[:, 0], summed[:, 1]

    def poses(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        phi, offset = motion(t, 0)
        return T_board_imu0[:3, :3] @ Rotation.from_rotvec(phi).as_matrix(), T_board_imu0[:3, 3] + offset

    epoch = 1000.0
    t_cam = np.arange(0.0, duration_s, 1.0 / camera_hz)
    R_board_imu, p_board_imu = poses(t_cam)  # motion time is the camera's clock less the epoch
    T_imu_cam = invert(T_CAM_IMU)
    grid = BoardSpec.parse(BOARD).object_points.astype(np.float64)
    times, frames, pixels, points, T_cam_boards = [], [], [], [], []
    for k, (R, p) in enumerate(zip(R_board_imu, p_board_imu, strict=True)):
        T_board_cam = make_T(R, p) @ T_imu_cam
        in_camera = (grid - T_board_cam[:3, 3]) @ T_board_cam[:3, :3]
        uv = CAMERA.project(in_camera)
        seen = (in_camera[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= CAMERA.width - 1) & (uv[:, 1] >= 0) & (
            uv[:, 1] <= CAMERA.height - 1)
        if seen.sum() < 12:
            continue
        times.append(epoch + t_cam[k])
        T_cam_boards.append(invert(T_board_cam))
        frames.append(np.full(int(seen.sum()), len(times) - 1))
        pixels.append(uv[seen] + rng.normal(0, pixel_sigma, size=(int(seen.sum()), 2)))
        points.append(grid[seen])
    observations = BoardObservations(np.array(times), np.concatenate(frames), np.concatenate(pixels),
                                     np.concatenate(points))

    t_imu = np.arange(-0.5, duration_s + 0.5, 1.0 / imu_hz)
    phi, _ = motion(t_imu, 0)
    phi_rate, _ = motion(t_imu, 1)
    _, acceleration = motion(t_imu, 2)
    R_board_imu, _ = poses(t_imu)
    gyro_bias = rng.normal(0, 0.02, 3)
    accel_bias = rng.normal(0, 0.1, 3)
    rates = np.einsum("nij,nj->ni", right_jacobians(phi), phi_rate)
    force = np.einsum("nji,nj->ni", R_board_imu, acceleration - GRAVITY_BOARD)
    if intrinsics is not None:
        rates_gyro, force_gyro = rates @ intrinsics.R_gyro_accel.T, force @ intrinsics.R_gyro_accel.T
        rates = rates_gyro @ intrinsics.gyro_M.T + force_gyro @ intrinsics.g_sensitivity.T
        force = force @ intrinsics.accel_M.T
    imu = ImuSamples(epoch + offset_s + t_imu,  # the IMU's clock reads offset_s more at the same instant
                     rates + gyro_bias + rng.normal(0, gyro_sigma, rates.shape),
                     force + accel_bias + rng.normal(0, accel_sigma, force.shape))
    return CameraImuRecording(CAMERA, observations, imu, T_CAM_IMU, offset_s, gyro_bias, accel_bias,
                              np.array(T_cam_boards))


def write_images(recording: CameraImuRecording, folder: Path, frames: range) -> None:
    """Render ``frames`` of the recording as the camera saw them into ``folder``, each named by its time in ns."""
    board = BoardSpec.parse(BOARD)
    folder.mkdir(parents=True, exist_ok=True)
    for k in frames:
        image = render_board_image(recording.camera, board, recording.T_cam_board[k], np.random.default_rng(k))
        cv2.imwrite(str(folder / f"{round(recording.observations.t_s[k] * 1e9)}.png"), image)


def recording_files(recording: CameraImuRecording) -> tuple[bytes, bytes]:
    """The recording as the two CSV files a user uploads: IMU samples and detected corners (``t_ns`` columns)."""
    return format_imu_csv(recording.imu), format_detections_csv(recording.observations)
