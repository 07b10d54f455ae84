"""Camera-IMU calibration as the CLI, the API and the studio call it: read the files, fit, cross-check, judge, and
hand back one :class:`~backend.core.result.TransformResult`; in a session, the result is kept with the recording it
came from (its two CSV files beside it) and accepted as the rig's camera-IMU edge."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from backend.calib._session import check_camera, check_imu
from backend.calib.camera_imu.checks import (
    Excitation,
    HalvesCheck,
    ModelCheck,
    excitation,
    halves_check,
    judge,
    model_check,
    refuse_unexcited,
    widened,
)
from backend.calib.camera_imu.imu_model import IMU_MODELS as IMU_MODELS  # the studio's choices
from backend.calib.camera_imu.observations import (
    BoardObservations,
    check_board_points,
    detect_image_folder,
    parse_detections_csv,
    read_detections_csv,
)
from backend.calib.camera_imu.solver import DEFAULT_SETTINGS, CameraImuFit, CameraImuSettings, solve_camera_imu
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.result import ProgressCallback, TransformResult, no_progress
from backend.core.verdict import Verdict
from backend.devices.imu_csv import parse_imu_csv
from backend.devices.imu_files import read_imu
from backend.exports.ros_camera_info import load_camera_info
from backend.store.session import Session

KIND = "camera_imu"
MIN_HALF_S = 10.0
"""Each half of a recording must span this long (s) for the two-halves cross-check."""


def solve_recording(camera: CameraIntrinsics, observations: BoardObservations, imu: ImuSamples,
                    settings: CameraImuSettings = DEFAULT_SETTINGS, warnings: list[str] | None = None,
                    progress: ProgressCallback = no_progress) -> TransformResult:
    """Fit, cross-check on the two halves and with the other IMU model, and judge: ``T_camera_imu`` with its
    covariance and verdict; the time offset (``t_imu = t_cam + offset``) and everything behind the numbers in
    ``diagnostics``."""
    started = time.perf_counter()
    seen = imu.between(observations.t_s[0] - settings.max_offset_s, observations.t_s[-1] + settings.max_offset_s)
    if len(seen.t_s) < 100:
        raise InputError(f"the IMU has {len(seen.t_s)} sample(s) within the camera's {observations.t_s[0]:.3f}-"
                         f"{observations.t_s[-1]:.3f} s: the two streams do not overlap in time", "imu")
    motion = excitation(seen)
    refuse_unexcited(motion)
    fit = solve_camera_imu(camera, observations, imu, settings, lambda f, m: progress(0.4 * f, m))
    model: ModelCheck | None = None
    if settings.model_check:
        model = model_check(camera, observations, imu, fit, settings, lambda f, m: progress(0.4 + 0.2 * f, m))
    halves: HalvesCheck | None = None
    if observations.t_s[-1] - observations.t_s[0] >= 2 * MIN_HALF_S:
        halves = halves_check(camera, observations, imu, settings, lambda f, m: progress(0.6 + 0.38 * f, m))
    wide = widened(fit, halves, model)
    verdict = judge(fit, motion, halves, model, np.sqrt(np.diag(wide.covariance)))
    return _result(wide, fit, motion, halves, model, verdict, [*(warnings or []), *fit.warnings],
                   time.perf_counter() - started, settings)


def solve_files(camera_path: Path, corners: Path, imu_path: Path, board: str,
                settings: CameraImuSettings = DEFAULT_SETTINGS, progress: ProgressCallback = no_progress,
                imu_topic: str | None = None) -> TransformResult:
    """:func:`solve_recording` on a camera_info YAML, the board's corners (a detections CSV, or a folder of images
    named by their time stamps in ns, in which the board is detected) and the IMU's samples (a CSV as
    ``../shared/conventions.md`` says, a ``.lvx`` recording, or a bag's ``imu_topic``:
    :func:`~backend.devices.imu_files.read_imu`); :class:`InputError` naming the file at fault."""
    imu, warnings = read_imu(imu_path, imu_topic)
    camera, _ = load_camera_info(camera_path)
    detecting = corners.is_dir()

    def solving(fraction: float, message: str) -> None:  # after the detection's first fifth, if images were given
        progress(0.2 + 0.8 * fraction if detecting else fraction, message)

    if detecting:
        observations = detect_image_folder(corners, board, lambda f, m: progress(0.2 * f, m))
    else:
        observations = read_detections_csv(corners)
        check_board_points(observations, board, str(corners))
    return solve_recording(camera, observations, imu, settings, warnings, solving)


def solve_session(session: Session, imu_sensor: str, camera: str, imu_csv: tuple[str, bytes],
                  detections_csv: tuple[str, bytes], board: str, settings: CameraImuSettings = DEFAULT_SETTINGS,
                  progress: ProgressCallback = no_progress) -> str:
    """Solve ``T_camera_imu`` from an uploaded recording (``(file name, bytes)`` of the IMU CSV and of the
    detections CSV) through ``camera``'s intrinsics in the rig, and keep the result with both files beside it;
    returns its id. Files that cannot be used are refused naming them, and nothing is kept."""
    imu, observations = read_recording(session, imu_sensor, camera, imu_csv, detections_csv, board)
    intrinsics = session.rig.get(camera).intrinsics
    result = solve_recording(intrinsics, observations, imu[0], settings, imu[1], progress).named(camera, imu_sensor)
    files = {"imu.csv": imu_csv[1], "detections.csv": detections_csv[1]}
    record = result.to_record() | {"board": board, "sources": {"imu": imu_csv[0], "detections": detections_csv[0]}}
    return session.add_result(imu_sensor, record, inputs=[imu_csv[0], detections_csv[0]], files=files)


def read_recording(session: Session, imu_sensor: str, camera: str, imu_csv: tuple[str, bytes],
                   detections_csv: tuple[str, bytes], board: str
                   ) -> tuple[tuple[ImuSamples, list[str]], BoardObservations]:
    """The checked inputs of :func:`solve_session` (before any work is queued)."""
    check_imu(session, imu_sensor)
    check_camera(session, camera)
    if session.rig.get(camera).intrinsics is None:
        raise InputError(f"{camera} has no intrinsics yet: solve and accept them in step 3 first", "camera")
    imu = parse_imu_csv(imu_csv[1], imu_csv[0])
    observations = parse_detections_csv(detections_csv[1], detections_csv[0])
    check_board_points(observations, board, detections_csv[0])
    return imu, observations


def camera_imu_results(session: Session, imu_sensor: str) -> list[dict]:
    """The IMU's stored camera-IMU results, oldest first, as :func:`summary` gives each (with its id and camera)."""
    check_imu(session, imu_sensor)
    return [{"result_id": record["id"], "camera": record["parent"]} | summary(TransformResult.from_record(record))
            for record in session.results(imu_sensor, KIND)]


def _result(fit: CameraImuFit, raw: CameraImuFit, motion: Excitation, halves: HalvesCheck | None,
            model: ModelCheck | None, verdict: Verdict, warnings: list[str], seconds: float,
            settings: CameraImuSettings) -> TransformResult:
    """The fit (``fit``: its sigmas widened by the halves; ``raw``: as solved) as a transform result: covariance in
    :data:`~backend.core.result.TRANSFORM_PARAMETERS` order (translation along the camera's axes, rotation about the
    IMU's)."""
    R_cam_imu = fit.T_cam_imu[:3, :3]
    to_child = np.zeros((6, 7))
    to_child[:3, 3:6] = np.eye(3)
    to_child[3:, :3] = R_cam_imu.T  # a left perturbation in the camera's axes, as one about the IMU's
    covariance = to_child @ fit.covariance[:7, :7] @ to_child.T
    offset_std = float(np.sqrt(fit.covariance[6, 6]))
    return TransformResult(
        kind=KIND, method="spline", parent="camera", child="imu", T_parent_child=fit.T_cam_imu,
        covariance=covariance, residuals=dict(raw.residual_rms), converged=fit.converged, verdict=verdict,
        warnings=warnings, seconds=seconds,
        settings={k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()},
        diagnostics={
            "time_offset_s": fit.offset_s, "time_offset_std_s": offset_std,
            "white_noise_std": {"rot_deg": np.degrees(np.sqrt(np.diag(raw.covariance)[:3])).tolist(),
                                "trans_m": np.sqrt(np.diag(raw.covariance)[3:6]).tolist(),
                                "time_s": float(np.sqrt(raw.covariance[6, 6]))},
            "halves": None if halves is None else {"difference": halves.difference.tolist(),
                                                   "expected": halves.expected.tolist()},
            "imu_intrinsics": None if raw.imu_intrinsics is None else raw.imu_intrinsics.to_dict(),
            "model_check": None if model is None else {
                "model": model.model, "converged": model.fit.converged, "difference": model.difference.tolist(),
                "imu_intrinsics": (None if model.fit.imu_intrinsics is None
                                   else model.fit.imu_intrinsics.to_dict())},
            "excitation": motion.to_dict(), "noise_sigmas": dict(raw.sigmas),
            "gyro_bias_rad_s": raw.gyro_bias_rad_s.tolist(), "accel_bias_m_s2": raw.accel_bias_m_s2.tolist(),
            "gravity_board_m_s2": raw.gravity_board_m_s2.tolist(),
            "rate_alignment": {"offset_s": raw.alignment.offset_s, "correlation": raw.alignment.correlation,
                               "residual_rad_s": raw.alignment.residual_rad_s, "curve": raw.alignment.curve},
            "frames_used": raw.frames_used, "frames_total": raw.frames_total, "corners_used": raw.corners_used,
            "corners_dropped": raw.corners_dropped, "iterations": raw.iterations, "signals": raw.signals})


def summary(result: TransformResult) -> dict:
    """The ``camera-imu`` command's JSON (``../shared/conventions.md``)."""
    diagnostics = result.diagnostics
    return {"T_cam_imu": result.T_parent_child.tolist(), "time_offset_s": diagnostics["time_offset_s"],
            "std": result.std | {"time_s": diagnostics["time_offset_std_s"]}, "residuals": dict(result.residuals),
            "excitation": diagnostics["excitation"], "verdict": result.verdict.to_dict(),
            "imu_model": result.settings.get("imu_model", "calibrated"),  # results kept before the choice existed
            "imu_intrinsics": diagnostics.get("imu_intrinsics"),
            "converged": result.converged, "warnings": list(result.warnings), "seconds": result.seconds}

