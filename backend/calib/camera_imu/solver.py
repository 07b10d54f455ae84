"""Camera-IMU extrinsics and time offset from a board waved in front of the camera.

The pipeline follows Kalibr's ``kalibr_calibrate_imu_camera``:

1. the board's pose in every frame by PnP, through the camera's known lens;
2. the time offset by cross-correlating the camera's and the gyro's angular speeds, then the rotation and the gyro
   bias by aligning the rate vectors (:mod:`~backend.calib.camera_imu.time_offset`);
3. a spline trajectory of the IMU fitted to the board poses, gravity from the mean specific force;
4. one Levenberg-Marquardt fit of everything together (:mod:`~backend.calib.camera_imu.trajectory`): the spline,
   ``T_cam_imu``, the offset, constant gyro and accelerometer biases and gravity's direction, against every corner,
   gyro and accelerometer sample. Between rounds each measurement kind's noise sigma is re-estimated from its own
   residuals (so no noise file is needed, and the covariance is scaled by the noise the data show), and corners
   beyond :attr:`CameraImuSettings.outlier_sigmas` are dropped.

SciPy B-splines and a hand-assembled sparse normal matrix rather than gtsam's IMU factors: the time offset is a
parameter of the continuous trajectory here (gtsam's preintegrated factors sit between fixed keyframe times and have
no offset), and the whole fit of the 72 s EuRoC recording takes seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu import normal_equations
from backend.calib.camera_imu.imu_model import IMU_MODELS, ImuIntrinsics
from backend.calib.camera_imu.observations import BoardObservations, board_poses
from backend.calib.camera_imu.spline import UniformSpline
from backend.calib.camera_imu.time_offset import RateAlignment, align_rates, rates_from_rotations
from backend.calib.camera_imu.trajectory import (
    POSITION,
    Linearised,
    TrajectoryState,
    camera_residuals,
    imu_residuals,
)
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.result import ProgressCallback, no_progress
from backend.core.transforms import invert, make_T

NOISE_KINDS = ("reprojection_px", "gyro_rad_s", "accel_m_s2")


@dataclass(frozen=True)
class CameraImuSettings:
    """How the camera-IMU fit runs."""

    knots_per_s: float = 50.0
    """Knots of the trajectory spline per second (Kalibr's ``--pose-knots-per-second`` plays this role)."""
    degree: int = 5
    """Degree of the trajectory spline (5: Kalibr's order-6 pose spline; accelerations stay smooth)."""
    gravity_m_s2: float = 9.80665
    """Gravity's magnitude (m/s²) where the recording was made."""
    max_offset_s: float = 0.5
    """The time offset is searched within ± this (s)."""
    max_frame_rms_px: float = 3.0
    """Frames whose PnP leaves a larger RMS (px) are left out (a misdetected board)."""
    outlier_sigmas: float = 5.0
    """Corners whose residual exceeds this many of the reprojection sigma are dropped between rounds."""
    rounds: int = 3
    """Fits, each after re-estimating the noise sigmas and dropping outliers."""
    max_iterations: int = 30
    """Levenberg-Marquardt steps per round."""
    start_sigmas: tuple[float, float, float] = (1.0, 0.01, 0.1)
    """The noise sigmas of the first round: pixels (px), gyro (rad/s), accelerometer (m/s²) per sample; each
    round re-estimates them from the residuals."""
    imu_model: str = "calibrated"
    """The IMU's model (:data:`~backend.calib.camera_imu.imu_model.IMU_MODELS`, Kalibr's names): ``calibrated``
    takes its axes as ideal, ``scale-misalignment`` also fits their scale and misalignment."""
    model_check: bool = True
    """Fit the recording again with the other IMU model and widen the sigmas to the difference (the cross-check
    of :func:`~backend.calib.camera_imu.checks.model_check`)."""

    def __post_init__(self) -> None:
        if self.imu_model not in IMU_MODELS:
            raise InputError(f"imu_model must be one of {', '.join(IMU_MODELS)}, not {self.imu_model!r}",
                             "imu_model")


DEFAULT_SETTINGS = CameraImuSettings()


@dataclass
class CameraImuFit:
    """What the fit found, before it is judged."""

    T_cam_imu: np.ndarray
    offset_s: float
    covariance: np.ndarray
    """15x15 over the shared parameters (:data:`~backend.calib.camera_imu.trajectory.SHARED`): rotation in rad about
    the camera's axes, translation in m, offset in s, biases, gravity's two angles; then, with the
    ``scale-misalignment`` model, the IMU's 24 intrinsics."""
    sigmas: dict[str, float]
    """The noise sigmas (:data:`NOISE_KINDS`) the last round used, estimated from the residuals."""
    residual_rms: dict[str, float]
    """RMS of each kind's residuals in its unit."""
    gyro_bias_rad_s: np.ndarray
    """(3,) gyro bias (rad/s)."""
    accel_bias_m_s2: np.ndarray
    """(3,) accelerometer bias (m/s²)."""
    gravity_board_m_s2: np.ndarray
    imu_intrinsics: ImuIntrinsics | None
    """The IMU's scale and misalignment (``scale-misalignment``), None with the ``calibrated`` model."""
    alignment: RateAlignment
    """The angular-rate alignment the fit started from (an independent estimate of rotation and offset)."""
    frames_used: int
    frames_total: int
    corners_used: int
    corners_dropped: int
    converged: bool
    iterations: int
    signals: dict[str, list[float] | list[list[float]]] = field(default_factory=dict)
    """Measured and fitted gyro and accelerometer signals (decimated), for plots."""
    warnings: list[str] = field(default_factory=list)


def solve_camera_imu(camera: CameraIntrinsics, observations: BoardObservations, imu: ImuSamples,
                     settings: CameraImuSettings = DEFAULT_SETTINGS,
                     progress: ProgressCallback = no_progress) -> CameraImuFit:
    """Fit ``T_cam_imu`` and the time offset (``t_imu = t_cam + offset``) to a recording; :class:`InputError`
    when the recording cannot determine them (too few frames, no overlap, no rotation)."""
    progress(0.02, "posing the board in every frame")
    warnings: list[str] = []
    poses, rms = board_poses(camera, observations)
    usable = np.flatnonzero(np.isfinite(rms) & (rms <= settings.max_frame_rms_px))
    if len(usable) < 20:
        raise InputError(f"the board was posed in {len(usable)} frame(s) (of {len(observations.t_s)}); a camera-IMU "
                         "fit needs the board in view through the motion (at least 20 frames)", "detections")
    if len(usable) < len(observations.t_s):
        warnings.append(f"{len(observations.t_s) - len(usable)} of {len(observations.t_s)} frames left out (fewer "
                        f"than 8 corners, or PnP RMS above {settings.max_frame_rms_px} px)")
    frames = observations.subset(usable)
    poses = poses[usable]
    epoch = float(frames.t_s[0])
    frames = BoardObservations(frames.t_s - epoch, frames.frame, frames.pixels_px, frames.board_m)
    imu = ImuSamples(imu.t_s - epoch, imu.gyro_rad_s, imu.accel_m_s2, imu.saturated)

    progress(0.08, "aligning the camera's and the gyro's angular rates")
    R_board_cam = np.transpose(poses[:, :3, :3], (0, 2, 1))
    frame_step = float(np.median(np.diff(frames.t_s)))
    rate_times, camera_rates = rates_from_rotations(frames.t_s, R_board_cam, 2.5 * frame_step)
    alignment = align_rates(imu.t_s, imu.gyro_rad_s, rate_times, camera_rates, max_offset_s=settings.max_offset_s,
                            name="imu")
    padding = 2 * settings.max_offset_s / settings.rounds + 0.05
    start, end = frames.t_s[0] + alignment.offset_s - padding, frames.t_s[-1] + alignment.offset_s + padding
    imu_used = imu.between(max(start, imu.t_s[0]), min(end, imu.t_s[-1]))
    if imu_used.saturated is not None and imu_used.saturated.any():
        keep = ~imu_used.saturated
        imu_used = ImuSamples(imu_used.t_s[keep], imu_used.gyro_rad_s[keep], imu_used.accel_m_s2[keep])
    spline = UniformSpline(float(imu_used.t_s[0]), float(imu_used.t_s[-1]), 1.0 / settings.knots_per_s,
                           settings.degree)
    state = _initial_state(spline, frames.t_s + alignment.offset_s, poses, alignment, imu_used, settings)

    sigmas = dict(zip(NOISE_KINDS, settings.start_sigmas, strict=True))
    kept = frames
    dropped = 0
    converged, iterations = False, 0
    for round_index in range(settings.rounds):
        progress(0.15 + 0.75 * round_index / settings.rounds, f"fitting the trajectory (round {round_index + 1} of "
                 f"{settings.rounds})")
        state, converged, steps = _levenberg_marquardt(state, camera, kept, imu_used, sigmas, settings, progress)
        iterations += steps
        parts = _linearise(state, camera, kept, imu_used, sigmas, with_jacobian=False)
        error_px = np.hypot(*parts[0].residuals.reshape(-1, 2).T) * sigmas["reprojection_px"]  # whitened by the old
        for kind, part in zip(NOISE_KINDS, parts, strict=True):
            sigmas[kind] *= float(np.sqrt(np.mean(part.residuals**2)))
        if round_index < settings.rounds - 1:
            outliers = error_px > settings.outlier_sigmas * sigmas["reprojection_px"] * np.sqrt(2)
            if outliers.any():
                dropped += int(outliers.sum())
                kept = BoardObservations(kept.t_s, kept.frame[~outliers], kept.pixels_px[~outliers],
                                         kept.board_m[~outliers])

    progress(0.95, "the uncertainty of the fit")
    covariance = normal_equations.assemble(_linearise(state, camera, kept, imu_used, sigmas),
                                           spline).shared_covariance()
    residual_rms = _residual_rms(state, camera, kept, imu_used)
    return CameraImuFit(
        T_cam_imu=state.T_cam_imu, offset_s=state.offset_s, covariance=covariance, sigmas=sigmas,
        residual_rms=residual_rms, gyro_bias_rad_s=state.gyro_bias_rad_s, accel_bias_m_s2=state.accel_bias_m_s2,
        gravity_board_m_s2=state.gravity_board_m_s2, imu_intrinsics=state.intrinsics, alignment=alignment,
        frames_used=len(usable), frames_total=len(observations.t_s), corners_used=len(kept.frame),
        corners_dropped=dropped,
        converged=converged, iterations=iterations, signals=_signals(state, imu_used), warnings=warnings)


def _initial_state(spline: UniformSpline, imu_times: np.ndarray, T_cam_board: np.ndarray, alignment: RateAlignment,
                   imu: ImuSamples, settings: CameraImuSettings) -> TrajectoryState:
    """The spline fitted to the IMU's poses implied by the board poses and the aligned rotation (translation 0)."""
    T_cam_imu = make_T(alignment.R_a_b.T, np.zeros(3))
    T_board_imu = invert(T_cam_board) @ T_cam_imu
    rotations = Rotation.from_matrix(T_board_imu[:, :3, :3])
    R0 = rotations.mean().as_matrix()
    phi = (Rotation.from_matrix(R0.T) * rotations).as_rotvec()
    coefficients = spline.fit(imu_times, np.column_stack([T_board_imu[:, :3, 3], phi]))
    intrinsics = ImuIntrinsics.ideal() if settings.imu_model == "scale-misalignment" else None
    state = TrajectoryState(spline, coefficients, R0, T_cam_imu, alignment.offset_s, alignment.bias_a_rad_s.copy(),
                            np.zeros(3), np.array([0.0, 0.0, -settings.gravity_m_s2]), intrinsics)
    position_rate2 = spline.basis(imu.t_s, 2) @ coefficients[:, POSITION]
    _, R_board_imu = state.poses(imu.t_s)
    gravity = np.mean(position_rate2 - np.einsum("nij,nj->ni", R_board_imu, imu.accel_m_s2), axis=0)
    return replace(state, gravity_board_m_s2=settings.gravity_m_s2 * gravity / np.linalg.norm(gravity))


def _linearise(state: TrajectoryState, camera: CameraIntrinsics, frames: BoardObservations, imu: ImuSamples,
               sigmas: dict[str, float], with_jacobian: bool = True) -> list[Linearised]:
    """The camera's, the gyro's and the accelerometer's whitened residuals (:data:`NOISE_KINDS`' order)."""
    return [camera_residuals(state, camera, frames, sigmas["reprojection_px"], with_jacobian),
            *imu_residuals(state, imu, sigmas["gyro_rad_s"], sigmas["accel_m_s2"], with_jacobian)]


def _cost(state: TrajectoryState, camera: CameraIntrinsics, frames: BoardObservations, imu: ImuSamples,
          sigmas: dict[str, float]) -> float:
    return float(sum(part.residuals @ part.residuals
                     for part in _linearise(state, camera, frames, imu, sigmas, with_jacobian=False)))


def _levenberg_marquardt(state: TrajectoryState, camera: CameraIntrinsics, frames: BoardObservations,
                         imu: ImuSamples, sigmas: dict[str, float], settings: CameraImuSettings,
                         progress: ProgressCallback) -> tuple[TrajectoryState, bool, int]:
    """Damped Gauss-Newton steps until the cost stops falling; the state, whether it converged, the steps."""
    cost = _cost(state, camera, frames, imu, sigmas)
    damping = 1e-4
    for iteration in range(settings.max_iterations):
        equations = normal_equations.assemble(_linearise(state, camera, frames, imu, sigmas), state.spline)
        while True:
            step = equations.step(damping)
            trial = state.stepped(step)
            trial_cost = _cost(trial, camera, frames, imu, sigmas)
            if trial_cost < cost:
                break
            damping *= 10
            if damping > 1e8:
                return state, True, iteration + 1  # no step lowers the cost: at the minimum
        decrease = (cost - trial_cost) / cost
        state, cost = trial, trial_cost
        damping = max(damping / 10, 1e-9)
        if decrease < 1e-9:
            return state, True, iteration + 1
    return state, False, settings.max_iterations


def _residual_rms(state: TrajectoryState, camera: CameraIntrinsics, frames: BoardObservations,
                  imu: ImuSamples) -> dict[str, float]:
    """RMS of each measurement kind's residuals in its own unit (px per corner, rad/s, m/s² per sample)."""
    camera_part = camera_residuals(state, camera, frames, 1.0, with_jacobian=False)
    gyro_part, accel_part = imu_residuals(state, imu, 1.0, 1.0, with_jacobian=False)
    return {"reprojection_px": float(np.sqrt(np.mean(np.sum(camera_part.residuals.reshape(-1, 2) ** 2, axis=1)))),
            "gyro_rad_s": float(np.sqrt(np.mean(np.sum(gyro_part.residuals.reshape(-1, 3) ** 2, axis=1)))),
            "accel_m_s2": float(np.sqrt(np.mean(np.sum(accel_part.residuals.reshape(-1, 3) ** 2, axis=1))))}


def _signals(state: TrajectoryState, imu: ImuSamples, points: int = 1500) -> dict[str, list]:
    """The measured and fitted gyro and accelerometer signals at about ``points`` instants, for plots."""
    every = max(len(imu.t_s) // points, 1)
    sample = ImuSamples(imu.t_s[::every], imu.gyro_rad_s[::every], imu.accel_m_s2[::every])
    gyro_part, accel_part = imu_residuals(state, sample, 1.0, 1.0, with_jacobian=False)
    return {"t_s": sample.t_s.tolist(), "gyro_rad_s": sample.gyro_rad_s.tolist(),
            "gyro_fit_rad_s": (sample.gyro_rad_s + gyro_part.residuals.reshape(-1, 3)).tolist(),
            "accel_m_s2": sample.accel_m_s2.tolist(),
            "accel_fit_m_s2": (sample.accel_m_s2 + accel_part.residuals.reshape(-1, 3)).tolist()}

