"""A camera turned by a pan head (a servo) to several positions: one camera with a pan axis.

The servo-scanner rig turns its camera to the left, the centre and the right to cover the scanner's field. Rather
than one transform per position, the camera is one sensor with a pan axis in the LiDAR's frame: at a pan reading
``theta`` (rad),

    T_lidar_camera(theta) = P(theta) @ T_lidar_camera(0),    P(theta) = rotation by theta about the axis line,

the axis line being a unit direction ``a`` through a point ``c`` (m, LiDAR frame). So any position is predicted from
its reading. The ten parameters (the pose at zero as ``T_camera_lidar``, as every LiDAR-camera result holds it: 6;
the direction: 2; the point, across the axis: 2) are fitted to every position's board corners at once (their
reprojection error in pixels, the corner pairs of :func:`backend.calib.lidar_camera.sweep_corners.matched_pairs`),
starting from each position's own solve; their covariance is the fit's Jacobian's. Each position's own solve is the
cross-check: where the model puts the camera at that reading against where that position's corners alone put it,
in units of the own solve's sigma. The verdict (:func:`backend.calib.lidar_camera.checks.judge_pan_axis`) weighs
the pose's and the axis's sigmas and those cross-checks.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from backend.calib.lidar_camera.checks import judge_pan_axis
from backend.calib.lidar_camera.sweep_corners import CornerPlacement, matched_pairs, solve_sweep_corners
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import TransformResult, jacobian_covariance, transform_std
from backend.core.transforms import apply_params, invert, rotation_about_line, transform_error, transform_points
from backend.core.uncertainty import sigmas
from backend.core.verdict import Verdict

MIN_POSITIONS = 2
"""Fewest pan positions: two fix the axis's direction and its line."""
CROSS_CHECK_SIGMAS = 3.0
"""A position whose own solve lies farther than this many of its sigmas from the model's prediction disagrees."""
PAN_PARAMETERS = ["t_x_m", "t_y_m", "t_z_m", "r_x_rad", "r_y_rad", "r_z_rad", "axis_a_rad", "axis_b_rad",
                  "point_a_m", "point_b_m"]
"""Order of a pan-axis covariance: ``T_camera_lidar`` at reading 0 (as a transform result's), then the axis's
direction (rad) and its point (m), each along two unit vectors across the axis."""


@dataclass
class PanPosition:
    """The camera at one reading of the pan head, and the board placements it saw there."""

    pan_rad: float
    placements: list[CornerPlacement]


@dataclass
class PanAxisResult:
    """The camera's pose at pan reading zero, its pan axis, their covariance, each position's cross-check and the
    verdict."""

    T_lidar_camera_zero: np.ndarray
    """4x4 (m): the camera in the LiDAR's frame at pan reading 0."""
    axis: np.ndarray
    """(3,) unit direction of the pan axis in the LiDAR's frame (positive readings turn about it)."""
    axis_point_m: np.ndarray
    """(3,) the point of the axis line nearest the LiDAR's origin (m)."""
    covariance: np.ndarray
    """10x10 over :data:`PAN_PARAMETERS` (m, rad)."""
    rms_px: float
    """RMS reprojection error of every position's corners through the model (px)."""
    corners: int
    """Corner pairs fitted, over every position."""
    positions: list[dict[str, Any]]
    """Per position: its reading, corners, and how far its own solve lies from the prediction (mm, deg, sigmas)."""
    verdict: Verdict
    seconds: float

    @property
    def axis_sigma_deg(self) -> float:
        """1-sigma of the axis's direction (deg, the larger of its two components across the axis)."""
        return float(np.degrees(sigmas(self.covariance)[6:8].max()))

    @property
    def axis_point_sigma_m(self) -> float:
        """1-sigma of the axis line's place across itself (m, the larger of its two components)."""
        return float(sigmas(self.covariance)[8:10].max())

    @property
    def std(self) -> dict[str, list[float | None]]:
        """1-sigma of ``T_camera_lidar`` at reading 0: ``trans_m`` (m, camera axes), ``rot_deg`` (deg, LiDAR axes)."""
        return transform_std(self.covariance[:6, :6])

    def T_lidar_camera(self, pan_rad: float) -> np.ndarray:
        """The camera's pose at any pan reading (rad): the model's prediction."""
        return rotation_about_line(self.axis, self.axis_point_m, pan_rad) @ self.T_lidar_camera_zero

    def pan_axis(self) -> dict[str, Any]:
        """The axis as a result keeps it: ``axis`` and ``axis_point_m`` (LiDAR frame, m), ``axis_sigma_deg`` and
        ``axis_point_sigma_m``."""
        return {"axis": self.axis.tolist(), "axis_point_m": self.axis_point_m.tolist(),
                "axis_sigma_deg": self.axis_sigma_deg, "axis_point_sigma_m": self.axis_point_sigma_m}

    def transform(self, camera_frame: str = "camera", lidar_frame: str = "lidar") -> TransformResult:
        """The camera at reading 0 as a LiDAR-camera result of method ``pan_axis`` (``T_camera_lidar``, its
        covariance and the verdict; the axis, the positions' cross-checks and the whole covariance in its
        diagnostics): what a session keeps, and the rig takes as the camera's edge."""
        return TransformResult(
            kind="lidar_camera", method="pan_axis", parent=camera_frame, child=lidar_frame,
            T_parent_child=invert(self.T_lidar_camera_zero), covariance=self.covariance[:6, :6],
            residuals={"rms_px": self.rms_px, "corners": self.corners},
            diagnostics={"pan_axis": self.pan_axis(), "positions": self.positions,
                         "covariance_pan": self.covariance.tolist(), "covariance_pan_order": PAN_PARAMETERS},
            verdict=self.verdict, seconds=self.seconds)

    def summary(self) -> dict[str, Any]:
        """The CLI's JSON: ``{"T_camera_lidar", "std", "pan_axis", "residuals", "positions", "verdict",
        "seconds"}``, the transform and its sigma at reading 0."""
        return {"T_camera_lidar": invert(self.T_lidar_camera_zero).tolist(), "std": self.std,
                "pan_axis": self.pan_axis(), "residuals": {"rms_px": self.rms_px, "corners": self.corners},
                "positions": self.positions, "verdict": self.verdict.to_dict(), "seconds": self.seconds}


def _tangent_basis(axis: np.ndarray) -> np.ndarray:
    """(2, 3) two unit vectors across ``axis``."""
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    first = np.cross(axis, helper)
    first /= np.linalg.norm(first)
    return np.array([first, np.cross(axis, first)])


def _start(solves: list[tuple[float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis, axis point and pose at zero from the positions' own ``(reading, T_lidar_camera)``: the axis from the
    relative rotation of the two positions farthest apart, the point where it holds the cameras' centres."""
    (theta_a, T_a), (theta_b, T_b) = min(solves, key=lambda s: s[0]), max(solves, key=lambda s: s[0])
    rotvec = Rotation.from_matrix(T_b[:3, :3] @ T_a[:3, :3].T).as_rotvec()
    axis = rotvec / np.linalg.norm(rotvec) * np.sign(theta_b - theta_a)
    # t_b = R t_a + (I - R) c: the point on the axis in least squares (its part along the axis is free)
    R = T_b[:3, :3] @ T_a[:3, :3].T
    point = np.linalg.lstsq(np.eye(3) - R, T_b[:3, 3] - R @ T_a[:3, 3], rcond=None)[0]
    point -= axis * (axis @ point)
    return axis, point, rotation_about_line(axis, point, -theta_a) @ T_a


def solve_pan_axis(positions: Sequence[PanPosition], board: BoardSpec, camera: CameraIntrinsics,
                   T_guess: np.ndarray | None = None) -> PanAxisResult:
    """The pan-axis model of a camera from board corners at two or more pan positions (:class:`PanPosition`),
    judged; ``T_guess`` (``T_camera_lidar`` at reading 0, the mounting guess) pairs a half-turn-symmetric board's
    corners. :class:`InputError` for fewer than two positions or positions that do not turn the camera."""
    started = time.perf_counter()
    if len({round(p.pan_rad, 6) for p in positions}) < MIN_POSITIONS:
        raise InputError(f"{len(positions)} pan position(s): the axis needs at least {MIN_POSITIONS} different "
                         "readings", "positions")
    own, data = [], []
    for position in positions:
        guess = None if T_guess is None else guess_at_reading(T_guess, position.pan_rad)
        solve = solve_sweep_corners(position.placements, board, camera, "camera", "lidar", guess)
        own.append((position.pan_rad, invert(solve.T_parent_child), solve))
        pairs = [matched_pairs(p, board, camera, solve.T_parent_child) for p in position.placements]
        data.append((position.pan_rad, np.concatenate([q[0] for q in pairs]), np.concatenate([q[1] for q in pairs])))
    axis0, point0, T_zero0 = _start([(theta, T) for theta, T, _ in own])
    if abs(Rotation.from_matrix(own[-1][1][:3, :3] @ own[0][1][:3, :3].T).magnitude()) < np.radians(1.0):
        raise InputError("the positions' own solves differ by less than 1 deg: the pan head did not turn the camera",
                         "positions")
    basis = _tangent_basis(axis0)
    T_camera_lidar0 = invert(T_zero0)

    def model(params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        axis = axis0 + params[6:8] @ basis
        axis /= np.linalg.norm(axis)
        return invert(apply_params(T_camera_lidar0, params[:6])), axis, point0 + params[8:10] @ basis

    def residual(params: np.ndarray) -> np.ndarray:
        T_zero, axis, point = model(params)
        return np.concatenate([(camera.project(transform_points(
            invert(rotation_about_line(axis, point, theta) @ T_zero), points)) - pixels).ravel()
            for theta, points, pixels in data])

    fit = least_squares(residual, np.zeros(10), method="lm", x_scale=np.r_[[0.01] * 3, [0.001] * 5, [0.01] * 2])
    T_zero, axis, point = model(fit.x)
    result_positions = []
    for theta, _, solve in own:
        predicted = rotation_about_line(axis, point, theta) @ T_zero
        error_m, error_deg = transform_error(invert(predicted), solve.T_parent_child)
        own_std = solve.std
        ratio = max(np.max(np.abs(error_m) / np.array(own_std["trans_m"])),
                    np.max(np.abs(error_deg) / np.array(own_std["rot_deg"])))
        result_positions.append({"pan_deg": float(np.degrees(theta)), "corners": solve.residuals["corners"],
                                 "own_rms_px": solve.residuals["rms_px"],
                                 "from_prediction_mm": float(1000 * np.linalg.norm(error_m)),
                                 "from_prediction_deg": float(np.linalg.norm(error_deg)),
                                 "sigmas": float(ratio), "agrees": bool(ratio <= CROSS_CHECK_SIGMAS)})
    residuals = fit.fun.reshape(-1, 2)
    covariance = jacobian_covariance(fit, 10)
    std = sigmas(covariance)
    verdict = judge_pan_axis(transform_std(covariance[:6, :6]), float(np.degrees(std[6:8].max())),
                             float(std[8:10].max()), result_positions)
    return PanAxisResult(T_zero, axis, point, covariance, float(np.sqrt(np.mean(np.sum(residuals**2, axis=1)))),
                         len(residuals), result_positions, verdict, time.perf_counter() - started)


def camera_at_reading(T_camera_lidar_zero: np.ndarray, axis: np.ndarray, axis_point_m: np.ndarray,
                      pan_rad: float) -> np.ndarray:
    """``T_camera_lidar`` (4x4, m) at pan reading ``pan_rad`` (rad) of a camera at ``T_camera_lidar_zero`` at
    reading 0, turned about the line through ``axis_point_m`` (m) along the unit ``axis`` (both LiDAR frame)."""
    return T_camera_lidar_zero @ invert(rotation_about_line(axis, axis_point_m, pan_rad))


def guess_at_reading(T_camera_lidar_guess: np.ndarray, pan_rad: float) -> np.ndarray:
    """What a mounting guess at reading 0 implies at ``pan_rad`` (rad): the camera turned about its own up axis (its
    optical frame's -y) through its centre."""
    T_lidar_camera = invert(T_camera_lidar_guess)
    return camera_at_reading(T_camera_lidar_guess, -T_lidar_camera[:3, 1], T_lidar_camera[:3, 3], pan_rad)
