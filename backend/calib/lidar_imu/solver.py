"""LiDAR-IMU rotation, time offset and, where the motion allows, translation.

The LiDAR's pose over time comes from its own scans (:mod:`~backend.calib.lidar_imu.odometry`); its angular rates,
between consecutive scans, are aligned with the gyro's by the camera-IMU solve's rate alignment
(:func:`~backend.calib.camera_imu.time_offset.align_rates`: the offset from the angular speeds' correlation, then the
rotation and the gyro bias by Kabsch). With those fixed, the accelerometer gives the translation (the lever arm,
:mod:`~backend.calib.lidar_imu.lever_arm`: a linear least-squares solve with gravity and the accelerometer's bias)
when the rig turned enough about every axis; when it did not, the result says the translation is not determined,
its sigma is undetermined, and it stays the mounting guess. The two halves of the recording are solved on their own
as the cross-check, and each reported sigma is the larger of the solve's and the halves' spread.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.checks import MIN_RATE_RMS_RAD_S, excitation
from backend.calib.camera_imu.time_offset import RateAlignment, align_rates, rates_from_rotations
from backend.calib.lidar_imu.lever_arm import GRAVITY_M_S2, LeverArm, solve_lever_arm
from backend.calib.lidar_imu.odometry import scan_poses
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.result import ProgressCallback, TransformResult, no_progress
from backend.core.transforms import make_T
from backend.core.verdict import VerdictBuilder

KIND = "lidar_imu"
ROTATION_TOLERANCE_DEG = 0.2
OFFSET_TOLERANCE_S = 0.002
TRANSLATION_TOLERANCE_M = 0.01


def solve_lidar_imu(scan_times_s: np.ndarray, scans: list[np.ndarray], imu: ImuSamples,
                    progress: ProgressCallback = no_progress) -> TransformResult:
    """``T_lidar_imu`` and the time offset ``t_imu = t_lidar + offset`` (in ``diagnostics``) from scans (points
    (N, 3) m in the LiDAR frame, at ``scan_times_s``) of a static scene taken while the rig turned, and the IMU's
    samples; where the motion does not determine the translation it is zero with an undetermined (NaN) sigma."""
    started = time.perf_counter()
    if len(scans) < 20:
        raise InputError(f"{len(scans)} scan(s): a LiDAR-IMU solve needs the rig turned through at least 20", "scans")
    poses, errors = scan_poses(scans, lambda f, m: progress(0.8 * f, m))
    scan_t = np.asarray(scan_times_s, float)
    step = float(np.median(np.diff(scan_t)))
    times, rates = rates_from_rotations(scan_t, poses[:, :3, :3], 2.5 * step)
    rms = np.sqrt(np.mean(rates**2, axis=0))
    idle = [axis for axis, r in zip("xyz", rms, strict=True) if r < MIN_RATE_RMS_RAD_S]
    if len(idle) > 1:
        raise InputError(f"the LiDAR turned about its {' and '.join(idle)} axes at most {rms.min():.2f} rad/s (RMS); "
                         f"the rotation needs turns about at least two axes of {MIN_RATE_RMS_RAD_S} rad/s", "scans")
    progress(0.85, "aligning the LiDAR's and the gyro's angular rates")
    whole = align_rates(imu.t_s, imu.gyro_rad_s, times, rates, name="imu")
    middle = len(times) // 2
    halves = [align_rates(imu.t_s, imu.gyro_rad_s, times[part], rates[part], name="imu")
              for part in (slice(0, middle), slice(middle, None))]
    rotation_spread = Rotation.from_matrix(halves[1].R_a_b @ halves[0].R_a_b.T).as_rotvec() / 2
    offset_spread = abs(halves[1].offset_s - halves[0].offset_s) / 2
    rotation_std = np.fmax(np.full(3, whole.rotation_std_rad), np.abs(rotation_spread))
    offset_std = max(whole.offset_std_s, offset_spread)
    progress(0.9, "the lever arm from the accelerometer")
    R_lidar_imu = whole.R_a_b.T
    lever = solve_lever_arm(scan_t, poses, imu, whole.offset_s, R_lidar_imu, whole.bias_a_rad_s)
    cut = len(scan_t) // 2
    lever_halves = [solve_lever_arm(scan_t[part], poses[part], imu, whole.offset_s, R_lidar_imu, whole.bias_a_rad_s)
                    for part in (slice(0, cut), slice(cut, None))]
    lever_spread = np.abs(lever_halves[1].t_lidar_imu_m - lever_halves[0].t_lidar_imu_m) / 2
    translation_std = (np.fmax(np.sqrt(np.diag(lever.covariance)), np.nan_to_num(lever_spread, nan=0.0))
                       if lever.determined else np.full(3, np.nan))
    covariance = np.diag(np.r_[translation_std**2, rotation_std**2])
    judge = VerdictBuilder()
    judge.sigma("rotation", float(np.degrees(rotation_std.max())), ROTATION_TOLERANCE_DEG, "deg")
    judge.sigma("time offset", 1e3 * offset_std, 1e3 * OFFSET_TOLERANCE_S, "ms")
    # each half's sigma is about sqrt(2) times the whole's, so their difference's is about twice the whole's
    halves_apart = float(np.linalg.norm(2 * rotation_spread))
    judge.cross_check_sigmas("two halves", halves_apart / max(2 * whole.rotation_std_rad, 1e-12),
                             f"the halves' rotations differ by {np.degrees(halves_apart):.3f} deg and their offsets by "
                             f"{2e3 * offset_spread:.2f} ms")
    _judge_translation(judge, lever, lever_halves, translation_std)
    return TransformResult(
        kind=KIND, method="rates", parent="lidar", child="imu",
        T_parent_child=make_T(R_lidar_imu, np.nan_to_num(lever.t_lidar_imu_m, nan=0.0)),
        covariance=covariance, residuals={"rate_rad_s": whole.residual_rad_s,
                                          "odometry_rmse_m": float(np.median(errors[1:]))},
        verdict=judge.verdict(), seconds=time.perf_counter() - started,
        diagnostics={"time_offset_s": whole.offset_s, "time_offset_std_s": offset_std,
                     "gyro_bias_rad_s": whole.bias_a_rad_s.tolist(), "correlation": whole.correlation,
                     "rate_rms_rad_s": rms.tolist(), "curve": whole.curve,
                     "excitation": excitation(imu.between(times[0] - 0.5, times[-1] + 0.5)).to_dict(), "halves": [
                         _alignment_summary(h) for h in halves], "lever_arm": lever.to_dict(),
                     "lever_arm_halves": [h.to_dict() for h in lever_halves]})


def _judge_translation(judge: VerdictBuilder, lever: LeverArm, halves: list[LeverArm],
                       translation_std: np.ndarray) -> None:
    """The translation's part of the verdict: determined or not, its sigma, gravity's magnitude and the halves."""
    if not lever.determined:
        judge.check(f"the translation is not determined by this motion (1-sigma {1e3 * lever.worst_std_m:.0f} mm along "
                    "its weakest direction): turn the rig faster about every axis; it stays the mounting guess")
        return
    judge.sigma("translation", 1e3 * float(translation_std.max()), 1e3 * TRANSLATION_TOLERANCE_M, "mm")
    # gravity's sigma as the translation's: the solve's, widened to the halves' spread where larger
    gravity_std = max(lever.gravity_std_m_s2, abs(halves[1].gravity_m_s2 - halves[0].gravity_m_s2) / 2)
    judge.cross_check_sigmas(
        "gravity", abs(lever.gravity_m_s2 - GRAVITY_M_S2) / max(gravity_std, 1e-9),
        f"the accelerometer's gravity came out {lever.gravity_m_s2:.3f} ± {gravity_std:.3f} m/s² against "
        f"{GRAVITY_M_S2} (the solve does not know it)")
    if all(h.determined for h in halves):
        apart = halves[1].t_lidar_imu_m - halves[0].t_lidar_imu_m
        expected = np.sqrt(np.diag(halves[0].covariance) + np.diag(halves[1].covariance))
        judge.cross_check_sigmas("two halves (translation)", float(np.max(np.abs(apart) / expected)),
                                 f"the halves' translations differ by {1e3 * np.linalg.norm(apart):.1f} mm")
    else:
        judge.missing_check("two halves (translation)", "a half of the recording alone did not determine it")


def _alignment_summary(alignment: RateAlignment) -> dict:
    return {"offset_s": alignment.offset_s, "R_imu_lidar": alignment.R_a_b.tolist(),
            "residual_rad_s": alignment.residual_rad_s}
