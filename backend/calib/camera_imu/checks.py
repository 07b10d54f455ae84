"""How far a camera-IMU fit can be trusted: the motion's excitation, a two-halves cross-check, the IMU model's
sensitivity, and the verdict.

The fit's own covariance assumes white noise on every sample; on real recordings the errors are correlated in time
(vibration, the spline's limits), and on EuRoC that covariance claims 0.1 mm where the two halves of the recording
disagree by 3 mm. So the reported sigma of each parameter is the larger of the covariance's and the halves' spread
(half their difference: the spread of the whole recording's estimate), as the intrinsics solve widens its sigma by
a jackknife; the halves' agreement against that is the cross-check.

The IMU's model is a second source of error no white-noise sigma sees: on EuRoC, fitting the ADIS16448's scale and
misalignment (0.1-0.5 % and up to 0.4 deg) moves the translation by 5 mm and the rotation by 0.2 deg (mostly the
turn between the gyro and accelerometer triads, which the ``calibrated`` model takes as one frame) while the
residuals fall by 1-2 %; the recording cannot tell the two models apart. So the fit is repeated with the other model
and the sigmas are widened to the difference (:func:`model_check`), which the verdict names.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.imu_model import IMU_MODELS
from backend.calib.camera_imu.observations import BoardObservations
from backend.calib.camera_imu.solver import CameraImuFit, CameraImuSettings, solve_camera_imu
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.result import ProgressCallback, no_progress
from backend.core.verdict import Verdict, VerdictBuilder

MIN_RATE_RMS_RAD_S = 0.2
"""An axis is excited in rotation when the gyro's RMS about it reaches this (rad/s, about 11 deg/s)."""
MIN_ACCEL_STD_M_S2 = 0.4
"""An axis is excited in translation when the specific force along it varies by this much (m/s², 1-sigma)."""
TRANSLATION_TOLERANCE_M = 0.002
ROTATION_TOLERANCE_DEG = 0.05
OFFSET_TOLERANCE_S = 0.0005


@dataclass(frozen=True)
class Excitation:
    """How much the motion moved the IMU about and along each of its axes."""

    rate_rms_rad_s: np.ndarray
    """(3,) RMS angular rate about x, y, z (rad/s)."""
    accel_std_m_s2: np.ndarray
    """(3,) standard deviation of the specific force along x, y, z (m/s²)."""

    @property
    def rotation_excited(self) -> np.ndarray:
        return self.rate_rms_rad_s >= MIN_RATE_RMS_RAD_S

    @property
    def translation_excited(self) -> np.ndarray:
        return self.accel_std_m_s2 >= MIN_ACCEL_STD_M_S2

    def to_dict(self) -> dict:
        return {"rate_rms_rad_s": self.rate_rms_rad_s.tolist(), "accel_std_m_s2": self.accel_std_m_s2.tolist(),
                "rotation_excited": self.rotation_excited.tolist(),
                "translation_excited": self.translation_excited.tolist(),
                "min_rate_rms_rad_s": MIN_RATE_RMS_RAD_S, "min_accel_std_m_s2": MIN_ACCEL_STD_M_S2}


def excitation(imu: ImuSamples) -> Excitation:
    """The excitation of the IMU's samples (the part of the recording the camera saw)."""
    return Excitation(np.sqrt(np.mean(imu.gyro_rad_s**2, axis=0)), imu.accel_m_s2.std(axis=0))


def refuse_unexcited(motion: Excitation, name: str = "imu") -> None:
    """:class:`InputError` when an axis was not turned about (the rotation and the lever arm along it are then not
    determined), or the IMU was hardly moved at all."""
    idle = [axis for axis, excited in zip("xyz", motion.rotation_excited, strict=True) if not excited]
    if idle:
        rates = ", ".join(f"{a} {r:.2f}" for a, r in zip("xyz", motion.rate_rms_rad_s, strict=True))
        raise InputError(f"the motion did not turn the IMU about its {' and '.join(idle)} axis (RMS rate {rates} "
                         f"rad/s; each needs {MIN_RATE_RMS_RAD_S} rad/s): wave the rig about every axis in turn, "
                         "in front of the board", name)
    if not motion.translation_excited.any():
        raise InputError("the IMU was hardly moved: the specific force varies by at most "
                         f"{motion.accel_std_m_s2.max():.2f} m/s² (each axis needs {MIN_ACCEL_STD_M_S2}): move the "
                         "rig along every axis as well as turning it", name)


@dataclass(frozen=True)
class HalvesCheck:
    """The fit repeated on the first and the second half of the frames."""

    difference: np.ndarray
    """(7,) second less first: rotation (rad, about the camera's axes), translation (m), offset (s)."""
    expected: np.ndarray
    """(7,) 1-sigma of that difference from the two halves' own covariances."""


def halves_check(camera: CameraIntrinsics, observations: BoardObservations, imu: ImuSamples,
                 settings: CameraImuSettings, progress: ProgressCallback = no_progress) -> HalvesCheck:
    """Fit each half of the frames on its own (with the IMU samples of its time)."""
    middle = len(observations.t_s) // 2
    fits = []
    for index, frames in enumerate((np.arange(middle), np.arange(middle, len(observations.t_s)))):
        progress(index / 2, f"cross-check: fitting the {('first', 'second')[index]} half alone")
        fits.append(solve_camera_imu(camera, observations.subset(frames), imu, settings))
    first, second = fits
    rotation = Rotation.from_matrix(second.T_cam_imu[:3, :3] @ first.T_cam_imu[:3, :3].T).as_rotvec()
    difference = np.concatenate([rotation, second.T_cam_imu[:3, 3] - first.T_cam_imu[:3, 3],
                                 [second.offset_s - first.offset_s]])
    expected = np.sqrt(np.diag(first.covariance)[:7] + np.diag(second.covariance)[:7])
    return HalvesCheck(difference, expected)


@dataclass(frozen=True)
class ModelCheck:
    """The fit repeated with the other IMU model."""

    model: str
    """The other model's name (:data:`~backend.calib.camera_imu.imu_model.IMU_MODELS`)."""
    fit: CameraImuFit
    difference: np.ndarray
    """(7,) the other model's less this one's: rotation (rad, about the camera's axes), translation (m), offset (s).
    The IMU's frame is the accelerometer triad's in the ``scale-misalignment`` model and both triads' in
    ``calibrated``, so the rotation's difference includes the turn between the triads, as a user of the result
    would meet it."""


def model_check(camera: CameraIntrinsics, observations: BoardObservations, imu: ImuSamples, fit: CameraImuFit,
                settings: CameraImuSettings, progress: ProgressCallback = no_progress) -> ModelCheck:
    """Fit the recording again with the IMU model ``settings`` does not use, and compare it with ``fit``."""
    other = next(model for model in IMU_MODELS if model != settings.imu_model)
    progress(0.0, f"cross-check: fitting again with the {other} IMU model")
    alternative = solve_camera_imu(camera, observations, imu, replace(settings, imu_model=other))
    rotation = Rotation.from_matrix(alternative.T_cam_imu[:3, :3] @ fit.T_cam_imu[:3, :3].T).as_rotvec()
    difference = np.concatenate([rotation, alternative.T_cam_imu[:3, 3] - fit.T_cam_imu[:3, 3],
                                 [alternative.offset_s - fit.offset_s]])
    return ModelCheck(other, alternative, difference)


def reported_sigmas(fit: CameraImuFit, halves: HalvesCheck | None, model: ModelCheck | None) -> np.ndarray:
    """(7,) reported 1-sigma of rotation (rad), translation (m) and offset (s): the fit's covariance, widened to the
    halves' spread (half their difference) and to the other IMU model's difference where those are larger."""
    sigma = np.sqrt(np.diag(fit.covariance)[:7])
    if halves is not None:
        sigma = np.fmax(sigma, np.abs(halves.difference) / 2)
    if model is not None and model.fit.converged:
        sigma = np.fmax(sigma, np.abs(model.difference))
    return sigma


def judge(fit: CameraImuFit, motion: Excitation, halves: HalvesCheck | None, model: ModelCheck | None,
          sigma: np.ndarray) -> Verdict:
    """The verdict: convergence, the sigmas against their tolerances, the angular-rate alignment, the halves and the
    other IMU model as cross-checks, and the excitation of translation."""
    builder = VerdictBuilder()
    if not fit.converged:
        builder.reject(f"the fit did not converge in {fit.iterations} steps")
    builder.sigma("translation", 1e3 * float(sigma[3:6].max()), 1e3 * TRANSLATION_TOLERANCE_M, "mm")
    builder.sigma("rotation", float(np.degrees(sigma[:3].max())), ROTATION_TOLERANCE_DEG, "deg")
    builder.sigma("time offset", 1e3 * float(sigma[6]), 1e3 * OFFSET_TOLERANCE_S, "ms")
    alignment = fit.alignment
    rotation = Rotation.from_matrix(fit.T_cam_imu[:3, :3] @ alignment.R_a_b).magnitude()
    spread = float(np.hypot(alignment.rotation_std_rad, np.linalg.norm(sigma[:3])))
    builder.cross_check_sigmas(
        "angular rates", float(rotation / max(spread, 1e-12)),
        f"the rotation from the angular rates alone (no accelerometer, no trajectory; RMS "
        f"{alignment.residual_rad_s:.3g} rad/s) differs from the fit's by {np.degrees(rotation):.3f} deg")
    offset_spread = float(np.hypot(alignment.offset_std_s, sigma[6]))
    builder.cross_check_sigmas(
        "speed correlation", abs(fit.offset_s - alignment.offset_s) / max(offset_spread, 1e-12),
        f"the offset at the peak of the angular speeds' correlation ({1e3 * alignment.offset_s:.2f} ms) differs from "
        f"the fit's by {1e3 * abs(fit.offset_s - alignment.offset_s):.2f} ms")
    if halves is None:
        builder.missing_check("two halves", "the recording was too short to fit each half alone")
    else:
        worst = float(np.max(np.abs(halves.difference) / np.maximum(halves.expected, 1e-12)))
        builder.note(f"two halves: they differ by {1e3 * np.linalg.norm(halves.difference[3:6]):.2f} mm, "
                     f"{np.degrees(np.linalg.norm(halves.difference[:3])):.3f} deg and "
                     f"{1e3 * abs(halves.difference[6]):.2f} ms ({worst:.0f} times the white-noise sigma, which is "
                     "why the reported sigma is their spread)")
    if model is None:
        builder.missing_check("IMU model", "the fit was not repeated with the other IMU model (model_check off)")
    elif not model.fit.converged:
        builder.missing_check("IMU model", f"the fit with the {model.model} IMU model did not converge")
    else:
        builder.note(f"IMU model: fitted with the {model.model} model instead, the translation moves "
                     f"{1e3 * np.linalg.norm(model.difference[3:6]):.2f} mm, the rotation "
                     f"{np.degrees(np.linalg.norm(model.difference[:3])):.3f} deg and the offset "
                     f"{1e3 * abs(model.difference[6]):.2f} ms; the reported sigma covers that")
    weak = [axis for axis, excited in zip("xyz", motion.translation_excited, strict=True) if not excited]
    if weak:
        builder.check(f"the IMU was hardly moved along its {' and '.join(weak)} axis (specific force spread "
                      f"below {MIN_ACCEL_STD_M_S2} m/s²): the translation along it rests on the rotation alone")
    return builder.verdict()


def widened(fit: CameraImuFit, halves: HalvesCheck | None, model: ModelCheck | None) -> CameraImuFit:
    """``fit`` with its covariance's first seven sigmas widened to :func:`reported_sigmas`, correlations kept."""
    sigma = reported_sigmas(fit, halves, model)
    own = np.sqrt(np.diag(fit.covariance))
    scale = np.ones(len(own))
    scale[:7] = sigma / np.maximum(own[:7], 1e-300)
    return replace(fit, covariance=fit.covariance * np.outer(scale, scale))

