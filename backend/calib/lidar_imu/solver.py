"""LiDAR-IMU rotation and time offset from angular rates.

The LiDAR's orientation over time comes from its own scans (:mod:`~backend.calib.lidar_imu.odometry`); its angular
rates, between consecutive scans, are aligned with the gyro's by the camera-IMU solve's rate alignment
(:func:`~backend.calib.camera_imu.time_offset.align_rates`: the offset from the angular speeds' correlation, then the
rotation and the gyro bias by Kabsch). The two halves of the recording are aligned on their own as the cross-check,
and the reported sigma is the larger of the alignment's and the halves' spread.

The translation is not estimated: from angular rates alone it is not observable, and a lever-arm fit against the
accelerometer needs the trajectory's accelerations, which scan-to-scan odometry at 10 Hz does not give to the
millimetre. The result says so, so the verdict is at best ``check`` and the translation stays the mounting guess.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu.checks import MIN_RATE_RMS_RAD_S, excitation
from backend.calib.camera_imu.time_offset import RateAlignment, align_rates, rates_from_rotations
from backend.calib.lidar_imu.odometry import scan_orientations
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.result import ProgressCallback, TransformResult, no_progress
from backend.core.transforms import make_T
from backend.core.verdict import VerdictBuilder

KIND = "lidar_imu"
ROTATION_TOLERANCE_DEG = 0.2
OFFSET_TOLERANCE_S = 0.002


def solve_lidar_imu(scan_times_s: np.ndarray, scans: list[np.ndarray], imu: ImuSamples,
                    progress: ProgressCallback = no_progress) -> TransformResult:
    """``T_lidar_imu`` (rotation; translation not estimated) and the time offset ``t_imu = t_lidar + offset`` in
    ``diagnostics``, from scans (points (N, 3) m in the LiDAR frame, at ``scan_times_s``) of a static scene taken
    while the rig turned, and the IMU's samples."""
    started = time.perf_counter()
    if len(scans) < 20:
        raise InputError(f"{len(scans)} scan(s): a LiDAR-IMU solve needs the rig turned through at least 20", "scans")
    orientations, errors = scan_orientations(scans, lambda f, m: progress(0.8 * f, m))
    step = float(np.median(np.diff(scan_times_s)))
    times, rates = rates_from_rotations(np.asarray(scan_times_s, float), orientations, 2.5 * step)
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
    covariance = np.diag(np.r_[np.full(3, np.nan), rotation_std**2])
    judge = VerdictBuilder()
    judge.sigma("rotation", float(np.degrees(rotation_std.max())), ROTATION_TOLERANCE_DEG, "deg")
    judge.sigma("time offset", 1e3 * offset_std, 1e3 * OFFSET_TOLERANCE_S, "ms")
    # each half's sigma is about sqrt(2) times the whole's, so their difference's is about twice the whole's
    halves_apart = float(np.linalg.norm(2 * rotation_spread))
    judge.cross_check_sigmas("two halves", halves_apart / max(2 * whole.rotation_std_rad, 1e-12),
                             f"the halves' rotations differ by {np.degrees(halves_apart):.3f} deg and their offsets by "
                             f"{2e3 * offset_spread:.2f} ms")
    judge.check("the translation is not estimated from angular rates: it stays the mounting guess")
    R_lidar_imu = whole.R_a_b.T
    return TransformResult(
        kind=KIND, method="rates", parent="lidar", child="imu", T_parent_child=make_T(R_lidar_imu, np.zeros(3)),
        covariance=covariance, residuals={"rate_rad_s": whole.residual_rad_s,
                                          "odometry_rmse_m": float(np.median(errors[1:]))},
        verdict=judge.verdict(), seconds=time.perf_counter() - started,
        diagnostics={"time_offset_s": whole.offset_s, "time_offset_std_s": offset_std,
                     "gyro_bias_rad_s": whole.bias_a_rad_s.tolist(), "correlation": whole.correlation,
                     "rate_rms_rad_s": rms.tolist(), "curve": whole.curve,
                     "excitation": excitation(imu.between(times[0] - 0.5, times[-1] + 0.5)).to_dict(), "halves": [
                         _alignment_summary(h) for h in halves]})


def _alignment_summary(alignment: RateAlignment) -> dict:
    return {"offset_s": alignment.offset_s, "R_imu_lidar": alignment.R_a_b.tolist(),
            "residual_rad_s": alignment.residual_rad_s}
