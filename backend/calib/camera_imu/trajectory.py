"""The continuous-time model of a camera-IMU recording and its residuals with their Jacobians.

The IMU's pose in the board's frame is a :class:`~backend.calib.camera_imu.spline.UniformSpline` of six values
``[p (m), phi (rad)]``, with ``R_board_imu(t) = R0 @ Exp(phi(t))`` (Kalibr's ``BSplinePose`` with its rotation-vector
parameterisation; ``R0`` a fixed reference orientation so ``phi`` stays far from pi). The gyro's and accelerometer's
biases are constant: on the 72 s EuRoC recording, Kalibr's random-walk bias splines (tried: twelve spline values,
four times the work) moved the translation by 0.3 mm and the offset by 7 µs. Three kinds of measurement constrain
it, each whitened by its own noise sigma:

- a board corner seen by the camera at ``t_cam``: the board point mapped through the pose at ``t_cam + offset``
  (Kalibr's ``t_imu = t_cam + offset``) and the extrinsic ``T_cam_imu``, projected by the (fixed) lens;
- a gyro sample: ``J_r(phi) dphi/dt + b_g``;
- an accelerometer sample: ``R_board_imu^T (d2p/dt2 - g_board) + b_a``;

both through the IMU's scale and misalignment when the fit has them (:mod:`~backend.calib.camera_imu.imu_model`).

The Jacobians are analytic except where a finite difference is cheaper and as exact in practice (the lens's
derivative by the normalised coordinates; the gyro's by ``phi``), and are returned per measurement by the six
spline values they touch, so the solver lifts them through the spline's sparse basis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu import imu_model
from backend.calib.camera_imu.imu_model import ImuIntrinsics, lower_triangle_jacobian
from backend.calib.camera_imu.observations import BoardObservations
from backend.calib.camera_imu.spline import UniformSpline
from backend.core.camera import CameraIntrinsics
from backend.core.imu import ImuSamples
from backend.core.transforms import right_jacobians, skew

VALUES = 6
"""Values of the spline: position (3), rotation vector (3)."""
POSITION, ROTATION = slice(0, 3), slice(3, 6)
SHARED = ("rot_cam_imu", "trans_cam_imu", "offset", "gyro_bias", "accel_bias", "gravity")
"""The parameters every measurement shares, in the solver's order after the spline's coefficients."""
SHARED_SIZES = (3, 3, 1, 3, 3, 2)
N_SHARED = sum(SHARED_SIZES)
SLICES = dict(zip(SHARED, (slice(a - n, a) for a, n in zip(np.cumsum(SHARED_SIZES), SHARED_SIZES, strict=True)),
                  strict=True))
"""Where each shared parameter sits in the shared block (rotation: a left perturbation of ``R_cam_imu`` in the
camera's axes, rad; translation of ``T_cam_imu`` in m; offset in s; biases in rad/s and m/s²; gravity: two angles
(rad) about the axes perpendicular to it."""
INTRINSICS = slice(N_SHARED, N_SHARED + imu_model.SIZE)
"""Where the IMU's intrinsics follow the shared parameters in a ``scale-misalignment`` fit."""
_LENS_STEP = 1e-7
"""Step (in normalised image units) of the finite difference of the lens's projection."""


@dataclass(frozen=True)
class TrajectoryState:
    """One point of the solve: the spline's coefficients and the shared parameters."""

    spline: UniformSpline
    coefficients: np.ndarray
    """(n, :data:`VALUES`) spline coefficients."""
    R0: np.ndarray
    """3x3 reference orientation of the IMU in the board's frame."""
    T_cam_imu: np.ndarray
    offset_s: float
    gyro_bias_rad_s: np.ndarray
    accel_bias_m_s2: np.ndarray
    gravity_board_m_s2: np.ndarray
    """(3,) gravity in the board's frame (m/s²); its length stays fixed."""
    intrinsics: ImuIntrinsics | None = None
    """The IMU's scale and misalignment (``scale-misalignment``), or None for an ideal IMU (``calibrated``)."""

    @property
    def n_shared(self) -> int:
        """Parameters after the spline's coefficients: :data:`SHARED`, then the IMU's intrinsics if fitted."""
        return N_SHARED + (imu_model.SIZE if self.intrinsics is not None else 0)

    def stepped(self, step: np.ndarray) -> TrajectoryState:
        """The state moved by ``step`` (the spline's coefficients, then :data:`SHARED` and :data:`INTRINSICS`)."""
        n = self.coefficients.size
        shared = step[n:]
        R = Rotation.from_rotvec(shared[SLICES["rot_cam_imu"]]).as_matrix() @ self.T_cam_imu[:3, :3]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, self.T_cam_imu[:3, 3] + shared[SLICES["trans_cam_imu"]]
        tilt = gravity_basis(self.gravity_board_m_s2) @ shared[SLICES["gravity"]]
        return replace(self, coefficients=self.coefficients + step[:n].reshape(-1, VALUES), T_cam_imu=T,
                       offset_s=self.offset_s + float(shared[SLICES["offset"]][0]),
                       gyro_bias_rad_s=self.gyro_bias_rad_s + shared[SLICES["gyro_bias"]],
                       accel_bias_m_s2=self.accel_bias_m_s2 + shared[SLICES["accel_bias"]],
                       gravity_board_m_s2=Rotation.from_rotvec(tilt).apply(self.gravity_board_m_s2),
                       intrinsics=None if self.intrinsics is None else self.intrinsics.stepped(shared[INTRINSICS]))

    def poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3; m) and orientations ``R_board_imu`` (N, 3, 3) at IMU times ``times_s``."""
        values = self.spline.basis(times_s) @ self.coefficients
        return values[:, POSITION], self.orientations(values[:, ROTATION])

    def orientations(self, phi: np.ndarray) -> np.ndarray:
        """``R_board_imu = R0 @ Exp(phi)`` (N, 3, 3) of the spline's rotation vectors ``phi`` (N, 3; rad)."""
        return self.R0 @ Rotation.from_rotvec(phi).as_matrix()


def gravity_basis(gravity: np.ndarray) -> np.ndarray:
    """3x2: two unit axes perpendicular to ``gravity``, about which its direction is perturbed."""
    down = gravity / np.linalg.norm(gravity)
    helper = np.eye(3)[int(np.argmin(np.abs(down)))]
    first = np.cross(down, helper)
    first /= np.linalg.norm(first)
    return np.column_stack([first, np.cross(down, first)])


@dataclass(frozen=True)
class Linearised:
    """Whitened residuals of one kind of measurement and their Jacobians, per measurement row."""

    residuals: np.ndarray
    """(R,) whitened residuals."""
    by_values: list[tuple[np.ndarray, int, np.ndarray, np.ndarray]]
    """For each spline derivative touched: ``(times (T,) s, derivative order, time (G,), J (G, rows, VALUES))``: the
    residuals come in G groups of ``rows`` (group ``g`` is residuals ``g * rows ...``), group ``g`` touching the
    spline's ``order``-th derivative at ``times[time[g]]``."""
    by_shared: np.ndarray
    """(R, n_shared) Jacobian by the shared parameters (:attr:`TrajectoryState.n_shared`)."""


def camera_residuals(state: TrajectoryState, camera: CameraIntrinsics, observations: BoardObservations,
                     sigma_px: float, with_jacobian: bool = True) -> Linearised:
    """Whitened reprojection residuals (u, v per corner, in ``sigma_px``) of every corner, and their Jacobians."""
    times = observations.t_s + state.offset_s
    basis = state.spline.basis(times)
    values = basis @ state.coefficients
    position, phi = values[:, POSITION], values[:, ROTATION]
    R_board_imu = state.orientations(phi)
    frame = observations.frame
    points_imu = np.einsum("mji,mj->mi", R_board_imu[frame], observations.board_m - position[frame])
    R_ci, t_ci = state.T_cam_imu[:3, :3], state.T_cam_imu[:3, 3]
    points_cam = points_imu @ R_ci.T + t_ci
    z = points_cam[:, 2]
    xy = points_cam[:, :2] / z[:, None]
    pixels = camera.project_normalised(xy)
    residuals = ((pixels - observations.pixels_px) / sigma_px).ravel()
    if not with_jacobian:
        return Linearised(residuals, [], np.zeros((0, state.n_shared)))
    lens = np.stack([(camera.project_normalised(xy + step) - pixels) / _LENS_STEP
                     for step in (np.array([_LENS_STEP, 0.0]), np.array([0.0, _LENS_STEP]))], axis=2)  # (M, 2, 2)
    perspective = np.zeros((len(z), 2, 3))
    perspective[:, 0, 0] = perspective[:, 1, 1] = 1 / z
    perspective[:, :, 2] = -xy / z[:, None]
    P = lens @ perspective / sigma_px  # (M, 2, 3): whitened residual by the point in the camera
    by_position = -P @ (R_ci @ np.transpose(R_board_imu, (0, 2, 1)))[frame]
    by_phi = P @ R_ci @ skew(points_imu) @ right_jacobians(phi)[frame]
    by_values = np.concatenate([by_position, by_phi], axis=2)  # (M, 2, VALUES)
    rate = state.spline.basis(times, 1) @ state.coefficients
    shared = np.zeros((len(z), 2, state.n_shared))
    shared[:, :, SLICES["rot_cam_imu"]] = -P @ skew(points_cam - t_ci)
    shared[:, :, SLICES["trans_cam_imu"]] = P
    shared[:, :, SLICES["offset"]] = (by_values @ rate[frame][:, :, None])
    return Linearised(residuals, [(times, 0, frame, by_values)], shared.reshape(-1, state.n_shared))


def imu_residuals(state: TrajectoryState, imu: ImuSamples, sigma_gyro: float, sigma_accel: float,
                  with_jacobian: bool = True) -> tuple[Linearised, Linearised]:
    """Whitened gyro and accelerometer residuals (3 per sample each, in ``sigma_gyro`` rad/s and ``sigma_accel``
    m/s²) and their Jacobians, through the state's IMU model (:mod:`~backend.calib.camera_imu.imu_model`)."""
    t = imu.t_s
    spline = state.spline
    values, rates, accelerations = (spline.basis(t, d) @ state.coefficients for d in range(3))
    phi, phi_rate = values[:, ROTATION], rates[:, ROTATION]
    J_r = right_jacobians(phi)
    omega = np.einsum("nij,nj->ni", J_r, phi_rate)
    R_board_imu = state.orientations(phi)
    R_imu_board = np.transpose(R_board_imu, (0, 2, 1))
    force = np.einsum("nij,nj->ni", R_imu_board, accelerations[:, POSITION] - state.gravity_board_m_s2)
    intrinsics = state.intrinsics or ImuIntrinsics.ideal()
    M_a = intrinsics.accel_M
    gyro_omega = intrinsics.gyro_M @ intrinsics.R_gyro_accel  # the gyro's measurement of the rate
    gyro_force = intrinsics.g_sensitivity @ intrinsics.R_gyro_accel  # ... and of the specific force
    gyro = ((omega @ gyro_omega.T + force @ gyro_force.T + state.gyro_bias_rad_s - imu.gyro_rad_s)
            / sigma_gyro).ravel()
    accel = ((force @ M_a.T + state.accel_bias_m_s2 - imu.accel_m_s2) / sigma_accel).ravel()
    if not with_jacobian:
        empty = np.zeros((0, state.n_shared))
        return Linearised(gyro, [], empty), Linearised(accel, [], empty)
    index = np.arange(len(t))
    step = 1e-7
    omega_by_phi = np.stack([(np.einsum("nij,nj->ni", right_jacobians(phi + step * e), phi_rate) - omega) / step
                             for e in np.eye(3)], axis=2)
    force_by_phi = skew(force) @ J_r
    by_gravity = skew(np.broadcast_to(state.gravity_board_m_s2, (len(t), 3))) @ gravity_basis(
        state.gravity_board_m_s2)  # d g / d angles = -[g]x E; the force takes -R^T of it
    force_by_gravity = R_imu_board @ by_gravity
    gyro_shared = np.zeros((len(t), 3, state.n_shared))
    gyro_shared[:, :, SLICES["gyro_bias"]] = np.eye(3)
    accel_shared = np.zeros((len(t), 3, state.n_shared))
    accel_shared[:, :, SLICES["accel_bias"]] = np.eye(3)
    accel_shared[:, :, SLICES["gravity"]] = M_a @ force_by_gravity
    gyro_blocks = [(t, 0, index, _placed(len(t), (ROTATION, gyro_omega @ omega_by_phi + gyro_force @ force_by_phi))),
                   (t, 1, index, _placed(len(t), (ROTATION, gyro_omega @ J_r)))]
    if state.intrinsics is not None:
        gyro_blocks.append((t, 2, index, _placed(len(t), (POSITION, gyro_force @ R_imu_board))))
        gyro_shared[:, :, SLICES["gravity"]] = gyro_force @ force_by_gravity
        accel_shared[:, :, INTRINSICS][:, :, imu_model.ACCEL_M] = lower_triangle_jacobian(force)  # into the view
        omega_gyro, force_gyro = omega @ intrinsics.R_gyro_accel.T, force @ intrinsics.R_gyro_accel.T
        by_intrinsics = gyro_shared[:, :, INTRINSICS]
        by_intrinsics[:, :, imu_model.GYRO_M] = lower_triangle_jacobian(omega_gyro)
        by_intrinsics[:, :, imu_model.GYRO_ROTATION] = (-intrinsics.gyro_M @ skew(omega_gyro)
                                                        - intrinsics.g_sensitivity @ skew(force_gyro))
        by_intrinsics[:, :, imu_model.G_SENSITIVITY] = np.einsum("ij,nk->nijk", np.eye(3), force_gyro).reshape(
            len(t), 3, 9)
    accel_blocks = [(t, 0, index, _placed(len(t), (ROTATION, M_a @ force_by_phi))),
                    (t, 2, index, _placed(len(t), (POSITION, M_a @ R_imu_board)))]
    return (_whitened(gyro, gyro_blocks, gyro_shared, sigma_gyro),
            _whitened(accel, accel_blocks, accel_shared, sigma_accel))


def _whitened(residuals: np.ndarray, blocks: list, shared: np.ndarray, sigma: float) -> Linearised:
    """The IMU residuals' :class:`Linearised`, the Jacobians divided by the noise ``sigma``."""
    return Linearised(residuals, [(times, order, index, J / sigma) for times, order, index, J in blocks],
                      shared.reshape(len(residuals), -1) / sigma)


def _placed(count: int, *blocks: tuple[slice, np.ndarray]) -> np.ndarray:
    """(count, 3, VALUES) Jacobians with each (count, 3, 3) block at its values' slice, zero elsewhere."""
    J = np.zeros((count, 3, VALUES))
    for where, block in blocks:
        J[:, :, where] = block
    return J
