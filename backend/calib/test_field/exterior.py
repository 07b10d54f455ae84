"""A camera's exterior orientation in a test field's frame: spatial resection from the surveyed markers it sees.

With the camera's intrinsics known, the pose ``T_wall_camera`` (the camera's optical frame in the wall's, m) is
found by PnP with RANSAC on the undistorted marker centres (a marker matched to the wrong survey row cannot pull
it), then refined by least squares on the reprojection error in pixels through the camera's own model (any model,
the photogrammetric one included). Sigma is the Jacobian's ``s^2 (J^T J)^-1`` with the residual variance, plus,
when the intrinsics' own sigma is given (:class:`~backend.calib.lidar_camera.lens_uncertainty.LensUncertainty`),
the lens's share: the pose found again with each intrinsic parameter moved by its 1-sigma, the moves combined with
the parameters' correlation (first order, by finite differences, as the board target method does); without it the
intrinsics are taken as exact, which the verdict says. The cross-check solves the pose again from each
half of the markers (alternating over the field, so both halves span it) and weighs the two poses' difference
against their own sigmas.

Also reported, as photogrammetric packages print it: the projection centre ``X0, Y0, Z0`` (m, wall frame) and
``omega, phi, kappa`` (deg, ``R_camera_wall = Rz(kappa) Ry(phi) Rx(omega)``).
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from scipy.optimize import least_squares

from backend.calib.board.detection import Detection
from backend.calib.intrinsics.photogrammetric import exterior_orientation
from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
from backend.calib.test_field.detection import MIN_MARKERS
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import TransformResult, jacobian_covariance
from backend.core.test_field import TestField
from backend.core.transforms import apply_params, invert, params_between, to_rvec_tvec, transform_points
from backend.core.uncertainty import sigmas
from backend.core.verdict import VerdictBuilder, judge_transform_sigmas

RANSAC_PX = 4.0
"""A marker centre farther than this (px) from the RANSAC pose's projection is an outlier (a wrong survey row, a
marker moved since the survey)."""


def _refine(camera: CameraIntrinsics, centres_m: np.ndarray, pixels: np.ndarray, T_wall_camera: np.ndarray):
    """Least-squares ``T_wall_camera`` from a start; returns the pose and SciPy's result (residuals in px)."""
    def residuals(p: np.ndarray) -> np.ndarray:
        T_camera_wall = invert(apply_params(T_wall_camera, p))
        return (camera.project(transform_points(T_camera_wall, centres_m)) - pixels).ravel()

    fit = least_squares(residuals, np.zeros(6), x_scale=np.r_[0.01, 0.01, 0.01, 1e-3, 1e-3, 1e-3])
    return apply_params(T_wall_camera, fit.x), fit


def _ransac_pose(camera: CameraIntrinsics, centres_m: np.ndarray, pixels: np.ndarray, name: str
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``T_wall_camera`` by PnP with RANSAC on undistorted centres, and the inlier mask."""
    normalised = camera.undistort_points(pixels).reshape(-1, 1, 2)
    threshold = RANSAC_PX / camera.K[0, 0]
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(centres_m.reshape(-1, 1, 3), normalised, np.eye(3), None,
                                                 reprojectionError=threshold, iterationsCount=500,
                                                 flags=cv2.SOLVEPNP_SQPNP)
    if not ok or inliers is None or len(inliers) < MIN_MARKERS:
        raise InputError(f"{name}: no camera pose fits {MIN_MARKERS} or more of the {len(pixels)} markers within "
                         f"{RANSAC_PX:g} px; check the survey file and the camera's intrinsics", name)
    mask = np.zeros(len(pixels), bool)
    mask[inliers.ravel()] = True
    R, _ = cv2.Rodrigues(rvec)
    T_camera_wall = np.eye(4)
    T_camera_wall[:3, :3], T_camera_wall[:3, 3] = R, tvec.ravel()
    return invert(T_camera_wall), mask


def _half_poses(camera: CameraIntrinsics, centres_m: np.ndarray, pixels: np.ndarray, T_start: np.ndarray
                ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """The pose and its 6x6 covariance from each half of the markers (alternate ones), or None if a half is too
    small to pose the camera with redundancy."""
    halves = [np.arange(len(pixels)) % 2 == k for k in range(2)]
    if min(h.sum() for h in halves) < MIN_MARKERS:
        return None
    out = []
    for half in halves:
        T, fit = _refine(camera, centres_m[half], pixels[half], T_start)
        out.append((T, jacobian_covariance(fit)))
    return out


def _lens_covariance(camera: CameraIntrinsics, lens: LensUncertainty, centres_m: np.ndarray, pixels: np.ndarray,
                     T_wall_camera: np.ndarray) -> np.ndarray:
    """(6, 6) the lens's share of the pose's covariance: the pose found again with each intrinsic parameter moved by
    its 1-sigma, the moves combined with the parameters' correlation."""
    moves = np.array([params_between(T_wall_camera, _refine(moved, centres_m, pixels, T_wall_camera)[0])
                      for moved in lens.moved(camera)])
    return moves.T @ lens.correlation @ moves


def resect(camera: CameraIntrinsics, test_field: TestField, detection: Detection, name: str,
           lens: LensUncertainty | None = None) -> TransformResult:
    """``T_wall_camera`` of the image ``name`` from its test-field ``detection``, with sigma (the lens's share
    included when ``lens`` gives the intrinsics' own sigma) and the verdict.

    Raises :class:`InputError` naming the image when too few markers are seen or no pose fits them."""
    started = time.perf_counter()
    if tuple(detection.image_size) != (camera.width, camera.height):
        raise InputError(f"{name} is {detection.image_size[0]}x{detection.image_size[1]} px but the camera is "
                         f"{camera.width}x{camera.height}", name)
    if len(detection.ids) < MIN_MARKERS:
        raise InputError(f"{name}: {len(detection.ids)} surveyed markers seen; a pose needs at least {MIN_MARKERS}",
                         name)
    centres_m = test_field.centres_m[detection.ids]
    T_start, inliers = _ransac_pose(camera, centres_m, detection.corners_px, name)
    T_wall_camera, fit = _refine(camera, centres_m[inliers], detection.corners_px[inliers], T_start)
    residuals_px = fit.fun.reshape(-1, 2)
    covariance = jacobian_covariance(fit)
    if lens is not None:
        covariance = covariance + _lens_covariance(camera, lens, centres_m[inliers], detection.corners_px[inliers],
                                                   T_wall_camera)
    marker_ids = np.array(test_field.ids)[detection.ids]
    result = TransformResult(
        kind="test_field", method="resection", parent="wall", child="camera", T_parent_child=T_wall_camera,
        covariance=covariance,
        residuals={"rms_px": float(np.sqrt(np.mean(np.sum(residuals_px**2, axis=1)))),
                   "markers_used": int(inliers.sum()), "markers_seen": len(inliers)},
        diagnostics={"markers": [{"id": int(i), "used": bool(u)} for i, u in zip(marker_ids, inliers, strict=True)],
                     "residuals_px": {str(int(i)): r.round(4).tolist()
                                      for i, r in zip(marker_ids[inliers], residuals_px, strict=True)},
                     "exterior_orientation": dict(zip(["X0_m", "Y0_m", "Z0_m", "omega_deg", "phi_deg", "kappa_deg"],
                                                      exterior_orientation(*to_rvec_tvec(invert(T_wall_camera)))
                                                      .tolist(), strict=True))},
        seconds=0.0)
    if not inliers.all():
        outliers = ", ".join(str(int(i)) for i in marker_ids[~inliers])
        result.warnings.append(f"{name}: marker(s) {outliers} are more than {RANSAC_PX:g} px off the pose the others "
                               "agree on; left out (moved since the survey, or surveyed wrong?)")
    result.verdict = _judge(result, _half_poses(camera, centres_m[inliers], detection.corners_px[inliers],
                                                T_wall_camera), lens)
    result.seconds = time.perf_counter() - started
    return result


def _judge(result: TransformResult, halves: list[tuple[np.ndarray, np.ndarray]] | None,
           lens: LensUncertainty | None):
    """The sigmas against the default tolerances, and the two halves' agreement as the cross-check (the lens's
    share left out of it: a lens error moves both halves alike)."""
    builder = VerdictBuilder()
    judge_transform_sigmas(builder, result.std)
    if halves is None:
        builder.missing_check("between the two halves of the markers", f"fewer than {2 * MIN_MARKERS} markers "
                              "were used, too few to pose the camera from each half")
    else:
        (T_a, cov_a), (T_b, cov_b) = halves
        difference = params_between(T_a, T_b)
        spread = np.sqrt(sigmas(cov_a) ** 2 + sigmas(cov_b) ** 2)
        ratio = float(np.max(np.abs(difference) / np.maximum(spread, 1e-12)))
        builder.cross_check_sigmas("between the two halves of the markers",
                                   ratio, f"the poses from alternate markers differ by "
                                   f"{1e3 * np.linalg.norm(difference[:3]):.1f} mm and "
                                   f"{np.degrees(np.linalg.norm(difference[3:])):.3f} deg")
    if lens is None:
        builder.note("the camera's intrinsics are taken as exact: their sigma is not carried into the pose")
    else:
        builder.note(f"the camera's intrinsics' sigma ({lens.source}) is carried into the pose's")
    return builder.verdict()
