"""LiDAR-to-camera from board corners found in a swept scanner's intensity image.

A 2D scanner swept by a servo sees a board's printed squares in its return intensity. Rendered as an image, one
row per servo step and one column per beam (:func:`~backend.core.sweep_geometry.intensity_image`), the board is a
checkerboard like any other, only coarse (a servo step of 1.05 deg against beams 0.25 deg apart), blurred by the
beam's footprint and in angles rather than a perspective. Pipeline (per placement of the board):

1. the image is resampled along the rows to square angular pixels (:data:`SQUARE_PIXELS`: the step over the beam
   spacing), so the corner detector and its sub-pixel refinement see the board undistorted by the anisotropy;
2. the board's corners are found there (OpenCV's classic detector, then the cameras' own; refined as the cameras'
   corners are, blur and all), and each corner's row and column mapped back to a servo angle (interpolated between
   the steps' read-back angles) and a beam angle;
3. each corner is lifted to 3D on its ray: the scanner's pose at that servo angle (the sweep's geometry) and the
   beam's direction, intersected with the board's plane fitted to the ranges of the returns inside the board
   (a plane through hundreds of ranges, not one range at the corner, whose beam straddles two squares);
4. the camera finds the same corners; since the LiDAR image may be mirrored or turned against the camera's view,
   the corner order is taken as whichever of the board's symmetric re-orderings the camera's PnP fits best.

The extrinsic comes from every placement's 3D-2D pairs at once: PnP with RANSAC on the undistorted corners, then
a least-squares refinement of the reprojection error in pixels; sigma from the Jacobian, widened to the
leave-one-placement-out spread (:func:`~backend.core.result.widen_covariance`). The verdict
(:func:`backend.calib.lidar_camera.checks.judge`) takes that spread as the cross-check between placements, as the
target method's between poses, and, given the sweeps' clouds, the target method's own answer on the same
placements (the board's plane and outline in the cloud, the camera's board pose): the corners and the plate are
different cues of the same data.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from backend.calib.board.detection import Detection, detect_board, detect_checkerboard_classic
from backend.calib.board.pose import board_pose, pnp_pose
from backend.calib.lidar_camera.checks import CrossCheck, compare_methods, judge
from backend.calib.lidar_camera.target import LidarCameraTargetSettings, TargetObservation, solve_target
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import TransformResult, jackknife_std, jacobian_covariance, widen_covariance
from backend.core.sweep_geometry import ScanAtAngle, SweepGeometry, SweepImage, intensity_image, stack_scans
from backend.core.transforms import apply_params, from_rvec_tvec, rotation_angle_deg, transform_points

MIN_SQUARE_PX = 3.0
"""A board whose squares span fewer rows than this in the intensity image is too small to find its corners."""
PLANE_INLIER_M = 0.03
"""Returns within this (m) of the board's plane fit it; farther ones (a hand, the stand behind) are left out."""
RANSAC_REPROJECTION_PX = 20.0
"""A 3D-2D pair farther than this (px) from the RANSAC PnP's projection is an outlier. The LiDAR's corners lie a
few millimetres off (a quarter of a servo step, RMS, and the beam spacing's as much across): about 5 px RMS in a
900 px camera at 0.7 m, so a tighter threshold throws good corners out and biases what is left."""
AMBIGUOUS_FIT = 1.5
"""Corner orderings whose PnP fits within this factor (plus 0.5 px) of the best are equally likely."""


@dataclass
class SweepCorners:
    """A board's corners in a sweep's intensity image and in 3D."""

    ids: np.ndarray
    """(N,) corner ids (row-major over the board's inner corners, as the detector orders them)."""
    image_px: np.ndarray
    """(N, 2) column and row of each corner in the intensity image (one row per servo step, one column per beam)."""
    points_m: np.ndarray
    """(N, 3) each corner in the sweep's (mount) frame (m), on the board plane."""
    plane_rms_m: float
    """RMS of the board's returns about its fitted plane (m)."""
    image: SweepImage
    """The intensity image the corners were found in."""


def sweep_image(scans: Sequence[ScanAtAngle], intensity_range: tuple[float, float] | None = None
                ) -> tuple[SweepImage, float]:
    """A sweep's intensity image, one row per step and one column per beam, and the beam spacing (rad);
    ``intensity_range`` maps to 1..255 (default the 1st..99th percentile, as
    :func:`~backend.core.sweep_geometry.intensity_image`)."""
    points, servo, intensity = stack_scans(scans)
    if not np.any(intensity):
        raise InputError("the sweep has no intensities: its scanner must report them to find a board's corners",
                         "sweep")
    beam = np.arctan2(points[:, 1], points[:, 0])
    first = np.sort(np.arctan2(scans[len(scans) // 2][1][:, 1], scans[len(scans) // 2][1][:, 0]))
    spacing = float(np.median(np.diff(first))) if len(first) > 1 else math.radians(0.25)
    columns = int(round((beam.max() - beam.min()) / spacing)) + 1
    image = intensity_image(points, intensity, servo, beam, (len(scans), columns),
                            servo_range_rad=(scans[0][0], scans[-1][0]), scan_range_rad=(beam.min(), beam.max()),
                            intensity_range=intensity_range)
    image.servo_angles_rad = np.array([angle for angle, _, _ in scans])  # each row is a step, as read back
    return image, spacing


def find_sweep_corners(scans: Sequence[ScanAtAngle], geometry: SweepGeometry, board: BoardSpec,
                       name: str = "sweep") -> SweepCorners:
    """The board's corners in a sweep (raw scans, as :meth:`SweptScanner.scans_of` gives them) assembled with
    ``geometry``; :class:`InputError` naming ``name`` when the board is not found or too small to be."""
    found = _detect_in_sweep(scans, board)
    if found is None:
        raise InputError(f"{name}: the board is not found in the sweep's intensity image; bring it closer (its squares "
                         f"should span {MIN_SQUARE_PX:g} servo steps or more) and keep it whole in the sweep", name)
    image, detection, stretch = found
    corners = _best_corners(detection)
    rows = (corners[:, 1] + 0.5) / stretch - 0.5
    square_rows = _square_size_px(corners, detection.ids, board) / stretch
    if square_rows < MIN_SQUARE_PX:
        raise InputError(f"{name}: the board's squares span {square_rows:.1f} servo steps, fewer than the "
                         f"{MIN_SQUARE_PX:g} its corners need; bring it closer or sweep in finer steps", name)
    image_px = np.column_stack([corners[:, 0], rows])
    origins, directions = _corner_rays(image, image_px, geometry)
    normal, offset, rms = _board_plane(scans, geometry, image, image_px)
    distance = (offset - origins @ normal) / (directions @ normal)
    return SweepCorners(detection.ids, image_px, origins + directions * distance[:, None], rms, image)


INTENSITY_SCALES: tuple[tuple[float, float] | None, ...] = (None, (0.0, 255.0))
"""The intensity scales the board is searched at: the image's own 1st..99th percentile, then a fixed one (0..255,
the sensors' usual range): a stretch set by the whole scene can leave a board's squares too alike to find."""
STRETCH_FACTORS = (1.0, 0.9, 1.1)
"""Row resampling factors tried, times the step over the beam spacing: the detector is sensitive to a board's
aspect, which a sweep only approximates (the rows follow the servo, not the board)."""


def _detect_in_sweep(scans: Sequence[ScanAtAngle], board: BoardSpec
                     ) -> tuple[SweepImage, Detection, float] | None:
    """The sweep's image, the board found in it resampled to square angles, and the row factor used; the scales of
    :data:`INTENSITY_SCALES` and factors of :data:`STRETCH_FACTORS` are tried in turn, each with OpenCV's classic
    detector and then the cameras' sector-based one. The image is blocky along its rows and curved by the sweep: on
    the servo-scanner rig's boards the sector-based detector missed about half of them at any one stretch, the
    classic one none but a board turned 20 deg; both detectors' corners are refined alike (the same to 0.01 px), and
    the classic detector was three times as fast. None when none finds it."""
    for scale in INTENSITY_SCALES:
        image, spacing = sweep_image(scans, scale)
        step = float(np.median(np.abs(np.diff(image.servo_angles_rad)))) if len(scans) > 1 else spacing
        for factor in STRETCH_FACTORS:
            stretch = max(step / spacing * factor, 1.0)
            size = (image.intensity.shape[1], int(round(image.intensity.shape[0] * stretch)))
            resampled = cv2.resize(image.intensity, size, interpolation=cv2.INTER_CUBIC)
            detection = detect_checkerboard_classic(resampled, board) or detect_board(resampled, board)
            if detection is not None:
                return image, detection, size[1] / image.intensity.shape[0]
    return None


def _best_corners(detection: Detection) -> np.ndarray:
    """The detector's refined corners when it has them (the first refinement), else its own."""
    return next(iter(detection.refined.values())) if detection.refined else detection.corners_px


def _square_size_px(corners: np.ndarray, ids: np.ndarray, board: BoardSpec) -> float:
    """The median distance (px) between corners next to each other along a board row."""
    cols = board.cols
    same_row = (ids[1:] == ids[:-1] + 1) & (ids[1:] % cols != 0)
    steps = np.linalg.norm(np.diff(corners, axis=0)[same_row], axis=1)
    return float(np.median(steps)) if len(steps) else 0.0


def _column_width_rad(image: SweepImage) -> float:
    """The beam angle (rad) one column of the intensity image spans (its columns are evenly spaced)."""
    columns = image.scan_angles_rad
    return float(columns[-1] - columns[0]) / max(len(columns) - 1, 1)


def _corner_rays(image: SweepImage, image_px: np.ndarray, geometry: SweepGeometry
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions (N, 3, mount frame) of the beams through image points (column, row)."""
    rows = np.arange(len(image.servo_angles_rad))
    servo = np.interp(image_px[:, 1], rows, image.servo_angles_rad)
    beam = image.scan_angles_rad[0] + image_px[:, 0] * _column_width_rad(image)
    origins, directions = [], []
    for s, a in zip(servo, beam, strict=True):
        T = geometry.T_mount_scanner(float(s))
        origins.append(T[:3, 3])
        directions.append(T[:3, :3] @ [math.cos(a), math.sin(a), 0.0])
    return np.array(origins), np.array(directions)


def _board_plane(scans: Sequence[ScanAtAngle], geometry: SweepGeometry, image: SweepImage,
                 image_px: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The board's plane ``normal . x = offset`` (mount frame) from the returns inside the corners' hull (shrunk
    towards its centre, so the plate's edges and what holds it stay out), and their RMS about it (m)."""
    points, servo, _ = stack_scans(scans)
    beam = np.arctan2(points[:, 1], points[:, 0])
    row = np.round(np.interp(servo, image.servo_angles_rad, np.arange(len(image.servo_angles_rad)))).astype(int)
    column = np.round((beam - image.scan_angles_rad[0]) / _column_width_rad(image)).astype(int)
    centre = image_px.mean(axis=0)
    hull = cv2.convexHull(np.round(centre + 0.9 * (image_px - centre)).astype(np.int32))
    mask = cv2.fillConvexPoly(np.zeros(image.intensity.shape, np.uint8), hull, 1).astype(bool)
    inside = mask[np.clip(row, 0, mask.shape[0] - 1), np.clip(column, 0, mask.shape[1] - 1)]
    board_points = geometry.transform(points[inside], servo[inside])
    if len(board_points) < 10:
        raise InputError(f"only {len(board_points)} returns fall on the board; bring it closer", "sweep")
    for _ in range(3):  # least squares, then again without the returns far from it
        centroid = board_points.mean(axis=0)
        normal = np.linalg.svd(board_points - centroid, full_matrices=False)[2][2]
        residual = (board_points - centroid) @ normal
        keep = np.abs(residual) < max(PLANE_INLIER_M, 3 * np.std(residual))
        if keep.all():
            break
        board_points = board_points[keep]
    return normal, float(centroid @ normal), float(np.sqrt(np.mean(residual[keep] ** 2)))


@dataclass
class CornerPlacement:
    """One placement of the board: its corners in the sweep and in the camera image."""

    name: str
    lidar: SweepCorners
    camera: Detection


def _orderings(board: BoardSpec) -> list[np.ndarray]:
    """The re-orderings of the board's corner ids under its symmetries: as is, turned a half turn, and mirrored
    along either axis (a mirrored LiDAR image orders its corners so)."""
    grid = np.arange(board.cols * board.rows).reshape(board.rows, board.cols)
    return [grid.ravel(), grid[::-1, ::-1].ravel(), grid[:, ::-1].ravel(), grid[::-1, :].ravel()]


def matched_pairs(placement: CornerPlacement, board: BoardSpec, camera: CameraIntrinsics, T_guess: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray]:
    """The placement's LiDAR corners (N, 3) and camera corners (N, 2, px) paired, in the ordering the camera's
    PnP of the LiDAR corners fits best. A board whose pattern is the same turned a half turn (odd squares both
    ways) fits as well both ways: then the ordering whose transform lies nearer ``T_guess`` (the mounting guess)
    is taken, and without one it is refused."""
    lidar = dict(zip(placement.lidar.ids.tolist(), placement.lidar.points_m, strict=True))
    pixels = dict(zip(placement.camera.ids.tolist(), _best_corners(placement.camera), strict=True))
    fits = []
    for ordering in _orderings(board):
        pairs = [(lidar[int(ordering[i])], pixels[i]) for i in pixels if int(ordering[i]) in lidar]
        if len(pairs) < 6:
            continue
        points, image = (np.array(part) for part in zip(*pairs, strict=True))
        T = pnp_pose(camera, points, image)
        if T is None:
            continue
        error = float(np.sqrt(np.mean(np.sum((camera.project(transform_points(T, points)) - image) ** 2, axis=1))))
        fits.append((error, T, points, image))
    if not fits:
        raise InputError(f"{placement.name}: too few corners seen by both the LiDAR and the camera", placement.name)
    least = min(fit[0] for fit in fits)
    alike = [fit for fit in fits if fit[0] <= AMBIGUOUS_FIT * least + 0.5]
    if len(alike) > 1 and T_guess is None:
        raise InputError(f"{placement.name}: the board's pattern looks the same turned a half turn, so its corners "
                         "pair two ways; give the mounting guess of the LiDAR in the camera to choose", placement.name)
    if len(alike) > 1:
        _, _, points, image = min(alike, key=lambda fit: rotation_angle_deg(fit[1][:3, :3].T @ T_guess[:3, :3]))
    else:
        _, _, points, image = min(fits, key=lambda fit: fit[0])
    return points, image


def solve_sweep_corners(placements: Sequence[CornerPlacement], board: BoardSpec, camera: CameraIntrinsics,
                        camera_frame: str, lidar_frame: str, T_guess: np.ndarray | None = None,
                        clouds: Sequence[np.ndarray] | None = None) -> TransformResult:
    """``T_camera_lidar`` from board corners in sweeps and images (one :class:`CornerPlacement` each), judged;
    ``T_guess``, the mounting guess, chooses how a half-turn-symmetric board's corners pair; ``clouds``, each
    placement's sweep assembled (mount frame, m), let the target method cross-check the result."""
    started = time.perf_counter()
    if not placements:
        raise InputError("no placement of the board to solve from", "placements")
    matched = [matched_pairs(p, board, camera, T_guess) for p in placements]
    points = np.concatenate([m[0] for m in matched])
    pixels = np.concatenate([m[1] for m in matched])
    owner = np.concatenate([np.full(len(m[0]), k) for k, m in enumerate(matched)])
    normalised = camera.undistort_points(pixels)
    focal = float(np.mean(np.diag(camera.K)[:2]))
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(points, normalised, np.eye(3), None,
                                                 reprojectionError=RANSAC_REPROJECTION_PX / focal,
                                                 iterationsCount=500, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or inliers is None or len(inliers) < 6:
        raise InputError("the LiDAR's and the camera's corners do not agree on one transform", "placements")
    keep = np.zeros(len(points), bool)
    keep[inliers.ravel()] = True
    fit = _refine(from_rvec_tvec(rvec, tvec), points[keep], pixels[keep], camera)
    T = apply_params(from_rvec_tvec(rvec, tvec), fit.x)
    cov_jacobian = jacobian_covariance(fit)
    spread = None
    if len(placements) >= 3:
        estimates = []
        for k in range(len(placements)):
            rest = keep & (owner != k)
            estimates.append(_refine(T, points[rest], pixels[rest], camera).x)
        spread = jackknife_std(np.array(estimates))
    covariance = widen_covariance(cov_jacobian, spread) if spread is not None else cov_jacobian
    residual = fit.fun.reshape(-1, 2)
    per_placement = {p.name: {"corners": int(np.sum(keep & (owner == k))),
                              "rms_px": float(np.sqrt(np.mean(np.sum(residual[owner[keep] == k] ** 2, axis=1))))
                              if np.any(keep & (owner == k)) else None,
                              "lidar_plane_rms_m": p.lidar.plane_rms_m}
                     for k, p in enumerate(placements)}
    result = TransformResult(
        kind="lidar_camera", method="corners", parent=camera_frame, child=lidar_frame, T_parent_child=T,
        covariance=covariance,
        residuals={"rms_px": float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))), "corners": int(keep.sum()),
                   "outliers": int((~keep).sum())},
        diagnostics={"placements": per_placement, "std_jacobian": np.sqrt(np.diag(cov_jacobian)).tolist(),
                     "std_spread": None if spread is None else spread.tolist()})
    judge(result, [_target_cross_check(result, placements, board, camera, clouds)])
    result.seconds = time.perf_counter() - started
    return result


def _target_cross_check(result: TransformResult, placements: Sequence[CornerPlacement], board: BoardSpec,
                        camera: CameraIntrinsics, clouds: Sequence[np.ndarray] | None) -> CrossCheck:
    """The target method on the same placements (the plate in the sweeps' clouds against the camera's board pose),
    compared with the corners' result in their combined sigmas; named missing without the clouds or when it
    cannot solve."""
    name = "the target method on the same placements"
    if clouds is None:
        return CrossCheck(name, "the sweeps' clouds were not given")
    observations = [TargetObservation(board_pose(camera, board, p.camera), np.asarray(cloud), p.name)
                    for p, cloud in zip(placements, clouds, strict=True)]
    try:
        target = solve_target(board, observations, result.T_parent_child,
                              LidarCameraTargetSettings(solve_plate_margin=True))
    except InputError as exc:
        return CrossCheck(name, f"it could not solve: {exc.message}")
    agreement = compare_methods(result.T_parent_child, result.covariance, target.T_parent_child, target.covariance,
                                "target")
    result.diagnostics["target_method"] = {"T_camera_lidar": target.T_parent_child.tolist(), "std": target.std,
                                           "sigmas": agreement.sigmas}
    return CrossCheck(name, agreement.detail(), agreement.sigmas)


def _refine(T_start: np.ndarray, points: np.ndarray, pixels: np.ndarray, camera: CameraIntrinsics):
    """Least squares over the six parameters of ``T_camera_lidar`` (about ``T_start``) of the corners'
    reprojection error (px)."""

    def residual(params: np.ndarray) -> np.ndarray:
        return (camera.project(transform_points(apply_params(T_start, params), points)) - pixels).ravel()

    return least_squares(residual, np.zeros(6), method="lm", x_scale=np.r_[0.01, 0.01, 0.01, 0.001, 0.001, 0.001])
