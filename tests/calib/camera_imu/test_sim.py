"""Camera-IMU calibration on a simulated recording with a known extrinsic, a 23 ms time offset and IMU biases; and
with an IMU whose axes are scaled and misaligned."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.imu_model import ImuIntrinsics
from backend.calib.camera_imu.service import solve_recording
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.sim.camera_imu import CameraImuRecording, simulate_recording

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recording() -> CameraImuRecording:
    return simulate_recording(duration_s=24.0, offset_s=0.023)


@pytest.fixture(scope="module")
def result(recording: CameraImuRecording) -> TransformResult:
    return solve_recording(recording.camera, recording.observations, recording.imu)


def test_offset_and_extrinsic_are_recovered_within_their_sigmas(recording, result) -> None:
    """Offset within 1 ms and rotation within 0.1 deg of the truth, each (and the translation) within 3 sigma."""
    offset_s, offset_std_s = result.diagnostics["time_offset_s"], result.diagnostics["time_offset_std_s"]
    assert abs(offset_s - recording.offset_s) < 1e-3, offset_s
    assert abs(offset_s - recording.offset_s) < 3 * offset_std_s, (offset_s, offset_std_s)
    T, truth = result.T_parent_child, recording.T_cam_imu
    rotation_deg = np.degrees(Rotation.from_matrix(T[:3, :3].T @ truth[:3, :3]).as_rotvec())  # about the IMU's axes
    assert np.linalg.norm(rotation_deg) < 0.1, rotation_deg
    assert (np.abs(rotation_deg) < 3 * np.array(result.std["rot_deg"])).all(), (rotation_deg, result.std)
    translation_m = T[:3, 3] - truth[:3, 3]
    assert np.linalg.norm(translation_m) < 2e-3, translation_m
    assert (np.abs(translation_m) < 3 * np.array(result.std["trans_m"])).all(), (translation_m, result.std)


def test_biases_are_estimated_and_the_verdict_is_trusted(recording, result) -> None:
    assert np.allclose(result.diagnostics["gyro_bias_rad_s"], recording.gyro_bias_rad_s, atol=2e-4)
    assert np.allclose(result.diagnostics["accel_bias_m_s2"], recording.accel_bias_m_s2, atol=1e-2)
    assert result.converged and result.verdict.level == "trusted", result.verdict.reasons
    reasons = " ".join(result.verdict.reasons)
    assert "cross-check angular rates" in reasons and "two halves" in reasons, reasons
    # the noise the residuals show is the noise the simulator added
    sigmas = result.diagnostics["noise_sigmas"]
    assert 0.25 < sigmas["reprojection_px"] < 0.35 and 0.0025 < sigmas["gyro_rad_s"] < 0.0035, sigmas


def test_motion_about_too_few_axes_is_refused_before_the_fit() -> None:
    slow = simulate_recording(duration_s=6.0, rotation_amplitude_rad=0.02, seed=1)
    with pytest.raises(InputError, match=r"did not turn the IMU about its x and y and z axis.*wave the rig"):
        solve_recording(slow.camera, slow.observations, slow.imu)


MISALIGNED = ImuIntrinsics(np.array([[1.01, 0, 0], [0.004, 0.995, 0], [-0.006, 0.008, 1.006]]),
                           np.array([[0.99, 0, 0], [0.005, 1.008, 0], [0.003, -0.004, 1.004]]),
                           Rotation.from_rotvec([0.004, -0.006, 0.003]).as_matrix(), np.zeros((3, 3)))
"""A MEMS IMU's errors: scales off by up to 1 %, axes misaligned by up to 0.5 deg, the gyro triad turned 0.45 deg."""


def test_an_imu_with_scale_and_misalignment_widens_the_calibrated_sigma_to_cover_its_error() -> None:
    """The ``calibrated`` fit of such an IMU is off by more than its white-noise sigma; its ``scale-misalignment``
    cross-check recovers the truth and the IMU's errors, and the reported sigma (widened to the two models'
    difference) covers the calibrated fit's error. 18 s: no two-halves check, so the IMU model is the only
    widening."""
    recording = simulate_recording(duration_s=18.0, offset_s=0.023, seed=2, intrinsics=MISALIGNED)
    result = solve_recording(recording.camera, recording.observations, recording.imu)
    T, truth = result.T_parent_child, recording.T_cam_imu
    error_m = T[:3, 3] - truth[:3, 3]
    error_deg = np.degrees(Rotation.from_matrix(T[:3, :3] @ truth[:3, :3].T).as_rotvec())  # about the camera's axes
    white_m = np.array(result.diagnostics["white_noise_std"]["trans_m"])
    assert (np.abs(error_m) > 5 * white_m).any(), (error_m, white_m)  # a bias the white-noise sigma does not see
    assert (np.abs(error_m) < 3 * np.array(result.std["trans_m"])).all(), (error_m, result.std)
    rotation_std_deg = np.degrees(np.sqrt(np.diag(result.covariance)[3:]))  # the covariance's, about the IMU's axes
    assert np.linalg.norm(error_deg) < 3 * np.linalg.norm(rotation_std_deg), (error_deg, rotation_std_deg)
    assert any(r.startswith("IMU model: fitted with the scale-misalignment model instead") for r in
               result.verdict.reasons) and result.verdict.level != "trusted", result.verdict.reasons

    check = result.diagnostics["model_check"]
    assert check["model"] == "scale-misalignment" and check["converged"]
    other = check["imu_intrinsics"]
    assert np.allclose(other["accel_M"], MISALIGNED.accel_M, atol=2.5e-3), other["accel_M"]  # 0.25 %
    assert np.allclose(other["gyro_M"], MISALIGNED.gyro_M, atol=1e-3), other["gyro_M"]
    turn = Rotation.from_matrix(np.array(other["R_gyro_accel"]) @ MISALIGNED.R_gyro_accel.T).magnitude()
    assert np.degrees(turn) < 0.05, np.degrees(turn)
    difference = np.array(check["difference"])
    assert np.linalg.norm(error_m + difference[3:6]) < 1e-3, (error_m, difference)  # the other model: the truth
