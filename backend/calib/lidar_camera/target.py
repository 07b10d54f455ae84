"""Target-based LiDAR-to-camera extrinsic calibration: ``T_camera_lidar`` from a board seen by both.

Each pose of the board gives one observation pair: the camera's board pose
``T_camera_board`` (PnP on the detected corners, :func:`camera_board_pose`) and the
LiDAR's cloud. Pipeline, as in the issue:

1. LiDAR side, per pose (:func:`find_board_points`): the points within the board plate's
   extent plus a margin around where the current ``T_camera_lidar`` puts the camera's
   board, a RANSAC plane on them (a RANSAC line for a 2D scanner) whose normal agrees with
   the camera's board normal, and the plate's edge points: the first and last board point of
   each scan line (ring of a spinning LiDAR, or the one line of a 2D scanner; lines are told
   apart by elevation), moved along its ray onto the fitted plane (removing the range noise, which
   on a turned board moves a point along the plate too) and out by half the point spacing.
2. Joint robust least squares over all poses of the 6 parameters of ``T_camera_lidar``
   (:func:`solve_target`): point-to-plane residuals of the board points against the
   camera's board plane, and edge residuals of the edge points against the nearest side
   of the plate outline in the board plane. The outline is taken symmetric about the
   plate centre, so a checkerboard whose axes PnP flipped by a half turn gives the same
   residuals. The board points are re-segmented with each refined estimate, with a
   tighter region each round (:attr:`LidarCameraTargetSettings.region_margins_m`).
3. Uncertainty: ``sigma^2 (J^T J)^-1`` at the solution and the leave-one-pose-out
   jackknife; the larger sigma per parameter is reported (poses are the independent
   units: the board's flatness, its pose error from PnP and the LiDAR's range bias move
   all points of a pose together, which a per-point noise model cannot see). With the camera's intrinsics'
   sigmas (each pose's ``T_camera_board_lens``), the lens's share is added: the solve re-run with every board
   pose from PnP with each intrinsic parameter moved by its 1-sigma (:func:`_lens_covariance`), so that a loosely
   known lens widens the result's sigma instead of hiding in it.

Parameters, covariance and sigmas follow :func:`backend.core.transforms.params_between`:
``[t_x, t_y, t_z]`` (m, along the camera's optical axes) and ``[r_x, r_y, r_z]`` (rad; reported
in deg) of a right perturbation ``R @ rotvec(r)``, i.e. about the LiDAR's (child frame's) axes,
as ``../shared/conventions.md`` asks.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from backend.calib.board.detection import Detection, detect_board
from backend.calib.board.pose import board_pose
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.clouds import check_cloud
from backend.core.errors import InputError
from backend.core.result import (
    ProgressCallback,
    TransformResult,
    finite_or_none,
    jackknife_std,
    jacobian_covariance,
    no_progress,
    widen_covariance,
)
from backend.core.transforms import apply_params, check_transform, invert, right_jacobian, transform_points
from backend.core.uncertainty import sigmas

MIN_POSES = 3
"""Fewest board poses for a solve: one plane fixes only 3 of the 6 parameters."""
RANSAC_SCORED_POINTS = 2000
"""Plane hypotheses are scored on at most this many of the region's points (a random subset)."""


@dataclass
class LidarCameraTargetSettings:
    """How to find the board in the clouds and solve. Lengths in metres, angles in degrees."""

    plate_margin_m: float = 0.0
    """White border of the board's plate beyond the printed pattern, on every side (m). The plate's
    outer edges are what the LiDAR sees; the demo board's plate has one square (0.04 m) of margin.
    With ``solve_plate_margin`` it is where the estimate starts."""
    solve_plate_margin: bool = False
    """Estimate the plate margin with the transform (a seventh parameter, common to every pose): the scan lines
    that cross the plate give its width. It is the border as the LiDAR sees it, its beam's footprint included
    (on the real VLP-16 set 1.2 cm for a thin printed border; a wrong margin of one square, 5 cm, left the edge
    points 37 mm RMS off the outline and the poses 2.5 times as spread)."""
    region_margins_m: tuple[float, ...] = (0.4, 0.1, 0.015)
    """Margin around the plate of the region searched for board points, in its plane and (added to
    ``plane_threshold_m``) along its normal, one segmentation round each (m). The first must cover
    the initial guess's error at the board (10 cm and 5 deg at 3 m is about 0.36 m); later rounds use
    the refined estimate and stay tight, so that the post and the floor just below the plate do not
    join its plane (a 4 cm margin biased the simulated solve by 1-2 mm)."""
    plane_threshold_m: float = 0.03
    """Largest distance from the RANSAC plane of a board point (m): about 3 range-noise sigmas."""
    max_normal_angle_deg: float = 15.0
    """Largest angle between the LiDAR plane's normal and the camera's board normal mapped by the
    current estimate (deg); planes beyond it (the floor, a wall) are not the board."""
    ransac_hypotheses: int = 300
    """Plane hypotheses drawn per pose and round."""
    min_plane_points: int = 30
    """Fewest plane inliers in the region for the board to count as found (3D LiDAR)."""
    min_line_points: int = 6
    """Fewest line inliers in the region for the board to count as found by a 2D scanner (a cloud whose
    points all have z = 0: the board is one line segment in the scan plane)."""
    line_gap_deg: float = 0.2
    """Elevation gap (deg) that separates two scan lines (rings) of the board points; below the ring
    spacing of any common LiDAR (VLP-16: 2 deg, 64 beams over 30 deg: 0.48 deg)."""
    min_points_per_line: int = 8
    """Fewest board points on a scan line for its two end points to count as edge points."""
    edge_weight: float | None = None
    """Weight of an edge residual relative to a point-to-plane residual; None weighs by inverse variance:
    the ratio of the robust sigmas (1.4826 MAD) of the plane and edge residuals at the previous round's
    estimate (1 in the first round). Edge points are about twice as precise as face points."""
    loss: str = "soft_l1"
    """Robust loss of :func:`scipy.optimize.least_squares`."""
    loss_scale_m: float = 0.03
    """Residual (m) where the robust loss starts to down-weight."""
    max_nfev: int = 200
    """Most residual evaluations per least-squares round."""
    max_plane_rms_m: float = 0.03
    """A solution whose point-to-plane RMS exceeds this (m) is a poor fit: ``converged=False``."""
    min_normal_eigenvalue: float = 1e-3
    """Smallest allowed eigenvalue of the mean ``n n^T`` of the board normals; below it the normals are
    (nearly) parallel or in one plane and part of the translation is unobservable. 1e-3 is a
    normal spread of about 2 deg rms."""
    spread: bool = True
    """Also estimate sigmas by the leave-one-pose-out jackknife and report the larger per parameter."""
    seed: int = 0
    """Seeds the RANSAC hypotheses, so a solve is repeatable."""


@dataclass
class TargetObservation:
    """One board pose seen by both sensors."""

    T_camera_board: np.ndarray
    """4x4 board pose in the camera's optical frame (m), e.g. from :func:`camera_board_pose`."""
    points_lidar: np.ndarray
    """(N, 3) LiDAR cloud in the LiDAR frame (m); extra columns (intensity) are ignored."""
    name: str = ""
    """How errors name this pose (e.g. ``"image_03.png:cloud_03.pcd"``); ``"pose i"`` when empty."""
    T_camera_board_lens: np.ndarray | None = None
    """(P, 4, 4) the board pose with each of P intrinsic parameters moved by its 1-sigma
    (:meth:`~backend.calib.lidar_camera.lens_uncertainty.LensUncertainty.board_poses`), or None: the lens's own
    uncertainty is then not carried into the result."""


@dataclass
class BoardPoints:
    """The board's points found in one pose's cloud (LiDAR frame, m)."""

    plane: np.ndarray
    """(N, 3) plane inliers within the region: the board's face."""
    edges: np.ndarray
    """(M, 3) scan-line end points, moved along their rays onto the fitted plane (the range noise, which on a
    turned board also moves a point along the plate, removed) and each moved out by half the line's point
    spacing so that on average it lies on the plate's outline (the first return on the board is between 0
    and one spacing inside the edge)."""


@dataclass
class PoseResiduals:
    """One pose's fit at the solution."""

    name: str
    plane_points: int
    edge_points: int
    plane_rms_m: float
    edge_rms_m: float
    without_m: float | None = None
    """How far the solve without this pose moves the result's translation (m, norm); None without a
    leave-one-out re-solve."""
    without_deg: float | None = None
    """And its rotation (deg, angle of the rotation between the two)."""
    without_sigmas: float | None = None
    """The largest parameter move of that re-solve in the Jacobian's sigmas: a pose far beyond the rest's
    :data:`~backend.calib.lidar_camera.checks.MAX_SPREAD_RATIO` pulls the result on its own."""

    def to_record(self) -> dict[str, Any]:
        return asdict(self)


# ---------------------------------------------------------------- camera side


def found_board(image: np.ndarray, board: BoardSpec, name: str = "image", detection: Detection | None = None
                ) -> Detection:
    """The board's corners in ``image``: ``detection`` (the corners already found in it) when given, else
    :func:`~backend.calib.board.detection.detect_board`'s; :class:`InputError` naming ``name`` when not found."""
    if detection is None:
        detection = detect_board(image, board)
    if detection is None:
        raise InputError(f"the board {board} was not found in the image", name)
    return detection


def camera_board_pose(image: np.ndarray, camera: CameraIntrinsics, board: BoardSpec, name: str = "image",
                      detection: Detection | None = None) -> np.ndarray:
    """``T_camera_board`` (4x4, m, optical frame) of the board detected in ``image`` (gray or BGR uint8).

    Detection by :func:`found_board`, pose by PnP on the undistorted corners
    (:func:`~backend.calib.board.pose.board_pose`). Raises :class:`InputError` naming ``name`` when the board is
    not found or PnP fails.
    """
    detection = found_board(image, board, name, detection)
    T = board_pose(camera, board, detection)
    if T is None:
        raise InputError(f"PnP failed on the {len(detection.ids)} detected corners", name)
    return T


# ---------------------------------------------------------------- the plate


def plate_centre_and_half_size(board: BoardSpec, plate_margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre (2,) of the plate in the board frame's x-y and its half width and height (2,) (m).

    The printed area spans :attr:`BoardSpec.outer_origin_m` to it plus :attr:`BoardSpec.size_m`; the
    plate adds ``plate_margin_m`` on every side. The centre is the corner grid's centre, so the
    outline is the same under the half turn a symmetric checkerboard's PnP may make.
    """
    size = np.asarray(board.size_m)
    return board.outer_origin_m[:2] + size / 2, size / 2 + plate_margin_m


def _nearest_side(points_board: np.ndarray, centre: np.ndarray, half: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For board-frame points (at least x, y; m): the signed in-plane distance (m) to the plate outline
    (positive outside), which board axis (0: x, 1: y) is across the side it is measured to, and the
    side's sign along it. Symmetric about the centre, so a half-turn flip of the board's axes changes
    nothing.

    The side is the one the point is furthest beyond (``max`` of the per-axis distances): inside the
    plate, the nearest side; outside, the side it lies beyond. A scan line's end above the plate's
    top corner is then as far off as it lies above the top, not on the side it ends at (the nearest
    side by absolute distance left a whole scan line above the plate unpenalised, and the real VLP-16
    set's upright boards, whose scan lines run parallel to the top and bottom, without any hold on
    their height but the board normals' few degrees of spread)."""
    offset = points_board[:, :2] - centre
    d = np.abs(offset) - half
    axis = (d[:, 1] > d[:, 0]).astype(int)
    rows = np.arange(len(d))
    return d[rows, axis], axis, np.where(offset[rows, axis] < 0, -1.0, 1.0)


def outline_distance(points_board: np.ndarray, centre: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Signed in-plane distance (m) of (N, 2+) board-frame points to the outline of the plate of ``centre`` (2,)
    and half size ``half`` (2,) (m; :func:`plate_centre_and_half_size`): positive outside, negative inside."""
    return _nearest_side(points_board, centre, half)[0]


# ---------------------------------------------------------------- LiDAR side


@dataclass
class PlaneFit:
    """A RANSAC plane (or a 2D scanner's line) refined by least squares on its inliers (sensor frame, m)."""

    inliers: np.ndarray
    """(N,) bool mask of the searched points within ``plane_threshold_m`` of the refined fit."""
    centroid: np.ndarray
    """(3,) mean of the inliers, a point of the fit."""
    normal: np.ndarray
    """(3,) unit normal of the plane (of a line: its normal within the scan plane, z = 0)."""


def fit_plane(points: np.ndarray, expected_normal: np.ndarray, settings: LidarCameraTargetSettings,
               rng: np.random.Generator) -> PlaneFit | None:
    """The RANSAC plane with the most inliers whose normal is within ``max_normal_angle_deg`` of
    ``expected_normal``, refined by a least-squares fit; None if none.

    Hand-written (vectorised numpy) rather than Open3D's ``segment_plane``: hypotheses are
    restricted to planes facing the way the camera says the board faces (so the floor or a wall
    in the region never wins), and the seeded generator makes a solve repeatable.
    """
    if len(points) < 3:
        return None
    samples = points[rng.integers(0, len(points), (settings.ransac_hypotheses, 3))]
    normals = np.cross(samples[:, 1] - samples[:, 0], samples[:, 2] - samples[:, 0])
    facing = _facing(normals, expected_normal, settings.max_normal_angle_deg)
    return _best_hypothesis(points, normals[facing], samples[facing, 0], settings, rng, line=False)


def _fit_line(points: np.ndarray, expected_normal: np.ndarray, settings: LidarCameraTargetSettings,
              rng: np.random.Generator) -> PlaneFit | None:
    """The RANSAC line, in a 2D scanner's x-y plane, along which the board's plane (``expected_normal``)
    cuts that plane, within ``max_normal_angle_deg``; None if none.

    Hand-written as :func:`fit_plane`; a hypothesis is the line through two points, its "normal"
    the line's normal within the scan plane, compared with the board normal's in-plane part.
    """
    expected = np.r_[expected_normal[:2], 0.0]
    if len(points) < 2 or np.linalg.norm(expected) < 1e-6:
        return None
    samples = points[rng.integers(0, len(points), (settings.ransac_hypotheses, 2))]
    along = samples[:, 1] - samples[:, 0]
    normals = np.column_stack([-along[:, 1], along[:, 0], np.zeros(len(along))])
    facing = _facing(normals, expected / np.linalg.norm(expected), settings.max_normal_angle_deg)
    return _best_hypothesis(points, normals[facing], samples[facing, 0], settings, rng, line=True)


def _facing(normals: np.ndarray, expected_normal: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """Which (unnormalised) hypothesis normals are within ``max_angle_deg`` of the unit ``expected_normal``."""
    length = np.linalg.norm(normals, axis=1)
    return np.abs(normals @ expected_normal) >= np.cos(np.radians(max_angle_deg)) * np.fmax(length, 1e-12)


def _best_hypothesis(points: np.ndarray, normals: np.ndarray, anchors: np.ndarray,
                     settings: LidarCameraTargetSettings, rng: np.random.Generator, line: bool) -> PlaneFit | None:
    """The hypothesis (a plane, or with ``line`` a line in the scan plane z = 0) with the most inliers among
    at most :data:`RANSAC_SCORED_POINTS` points, refined by a least-squares fit to its inliers."""
    if not len(normals):
        return None
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    scored = points[rng.choice(len(points), min(len(points), RANSAC_SCORED_POINTS), replace=False)]
    distances = np.abs(scored @ normals.T - np.einsum("ij,ij->i", anchors, normals))
    best = int(np.argmax((distances < settings.plane_threshold_m).sum(axis=0)))
    inliers = np.abs((points - anchors[best]) @ normals[best]) < settings.plane_threshold_m
    centroid = points[inliers].mean(axis=0)
    _, _, axes = np.linalg.svd(points[inliers] - centroid, full_matrices=False)
    normal = np.r_[-axes[0, 1], axes[0, 0], 0.0] if line else axes[2]
    return PlaneFit(np.abs((points - centroid) @ normal) < settings.plane_threshold_m, centroid, normal)


def onto_fit_along_rays(points: np.ndarray, fit: PlaneFit) -> np.ndarray:
    """``points`` (N, 3, sensor frame, m) moved along their rays from the sensor's origin onto the fitted plane
    (line): a LiDAR's range noise is along the ray, so this removes it while keeping each beam's direction.
    A ray within about 6 deg of the plane (a grazing hit, where a range error is no longer small) is kept as it is.
    """
    along = points @ fit.normal
    grazing = np.abs(along) < 0.1 * np.linalg.norm(points, axis=1)
    scale = np.where(grazing, 1.0, (fit.centroid @ fit.normal) / np.where(grazing, 1.0, along))
    return points * scale[:, None]


def scan_line_edges(points: np.ndarray, line_gap_deg: float, min_points: int) -> np.ndarray:
    """(M, 3) end points of the scan lines through board points (N, 3) in the sensor frame (m).

    Lines are runs of points whose elevation (angle from the sensor's x-y plane) differs by less
    than ``line_gap_deg``: the rings of a spinning LiDAR, or the one line of a 2D scanner (all
    z = 0). Along each line of at least ``min_points`` points (ordered by azimuth about the
    line's mean direction) the first and last points are moved out by half the mean spacing.
    """
    elevation = np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))
    order = np.argsort(elevation)
    line = np.r_[0, np.cumsum(np.diff(elevation[order]) > line_gap_deg)]
    edges = []
    for i in range(line[-1] + 1):
        members = points[order[line == i]]
        if len(members) < min_points:
            continue
        mean_x, mean_y = members[:, :2].mean(axis=0)
        mean_azimuth = np.arctan2(mean_y, mean_x)
        azimuth = np.angle(np.exp(1j * (np.arctan2(members[:, 1], members[:, 0]) - mean_azimuth)))
        members = members[np.argsort(azimuth)]
        half_step = (members[-1] - members[0]) / (2 * (len(members) - 1))
        edges += [members[0] - half_step, members[-1] + half_step]
    return np.array(edges).reshape(-1, 3)


def find_board_points(points_lidar: np.ndarray, T_camera_board: np.ndarray, T_camera_lidar: np.ndarray,
                      board: BoardSpec, margin_m: float, settings: LidarCameraTargetSettings,
                      rng: np.random.Generator, name: str) -> BoardPoints:
    """The board's face and edge points in one LiDAR cloud (m, LiDAR frame).

    The region is the plate (``settings.plate_margin_m`` included) plus ``margin_m`` (m) in its
    plane and within ``margin_m + settings.plane_threshold_m`` of it along its normal, placed by the
    camera's ``T_camera_board`` and the current ``T_camera_lidar``. A 3D cloud's board is a RANSAC
    plane there; a 2D scanner's (all points z = 0) a RANSAC line. Raises :class:`InputError` naming
    ``name`` when too few points of a plane (line) facing the camera's way are found there.
    """
    T_board_lidar = invert(T_camera_board) @ T_camera_lidar
    local = transform_points(T_board_lidar, points_lidar)
    centre, half = plate_centre_and_half_size(board, settings.plate_margin_m)
    depth = margin_m + settings.plane_threshold_m
    in_region = (np.abs(local[:, :2] - centre) <= half + margin_m).all(axis=1) & (np.abs(local[:, 2]) <= depth)
    region = points_lidar[in_region]
    expected_normal = T_board_lidar[2, :3]  # board z in LiDAR axes
    planar_scan = len(points_lidar) > 0 and not np.any(points_lidar[:, 2])
    fit, needed = (_fit_line, settings.min_line_points) if planar_scan else (fit_plane, settings.min_plane_points)
    plate = fit(region, expected_normal, settings, rng)
    found = 0 if plate is None else int(plate.inliers.sum())
    if found < needed:
        raise InputError(
            f"the board was not found in the LiDAR cloud: {found} plane points facing the camera's board normal "
            f"(within {settings.max_normal_angle_deg} deg) among the {len(region)} points within {margin_m} m of "
            f"where the current T_camera_lidar puts the plate; at least {needed} are needed - "
            "check that the LiDAR sees the board in this pose and the initial guess", name)
    face = region[plate.inliers]
    edges = scan_line_edges(onto_fit_along_rays(face, plate), settings.line_gap_deg, settings.min_points_per_line)
    return BoardPoints(face, edges)


# ---------------------------------------------------------------- the joint solve


def _find_boards(clouds: list[np.ndarray], T_camera_boards: list[np.ndarray], T_camera_lidar: np.ndarray,
                 board: BoardSpec, margin_m: float, settings: LidarCameraTargetSettings, rng: np.random.Generator,
                 names: list[str]) -> tuple[list[BoardPoints | None], list[str]]:
    """:func:`find_board_points` in every pose's cloud: the board's points (None where not found) and, for each pose
    where it was not, the message naming it."""
    found: list[BoardPoints | None] = []
    lost = []
    for cloud, T_camera_board, name in zip(clouds, T_camera_boards, names, strict=True):
        try:
            found.append(find_board_points(cloud, T_camera_board, T_camera_lidar, board, margin_m, settings, rng, name))
        except InputError as error:
            found.append(None)
            lost.append(f"{error.input}: {error.message}")
    return found, lost


def _check_pose_count(usable: int, total: int, skipped: list[str]) -> None:
    """Refuse fewer than :data:`MIN_POSES` usable poses of ``total``, saying why each of the others was ``skipped``."""
    if usable >= MIN_POSES:
        return
    why = f" ({'; '.join(skipped)})" if skipped else ""
    raise InputError(f"{usable} of {total} board poses are usable{why}; at least {MIN_POSES} are needed, with the "
                     "board tilted and turned differently in each", "poses")


def check_normals(normals: np.ndarray, threshold: float, advice: str = "tilt and turn the board between poses"
                  ) -> None:
    """Raise :class:`InputError` when the (N, 3) plane normals (camera frame) leave part of the translation
    unobservable: the smallest eigenvalue of their scatter is below ``threshold``; ``advice`` says what to do."""
    eigenvalues, eigenvectors = np.linalg.eigh(normals.T @ normals / len(normals))
    if eigenvalues[0] < threshold:
        axis = np.round(eigenvectors[:, 0], 2).tolist()
        raise InputError(
            f"degenerate poses: the plane normals are (nearly) parallel or in one plane (smallest "
            f"eigenvalue of their scatter {eigenvalues[0]:.2g} < {threshold:g}), so the translation along "
            f"{axis} (camera axes) is unobservable; {advice}", "poses")


@dataclass
class _Stacked:
    """All poses' board points stacked, each with its pose's board frame, so residuals are vectorised."""

    plane_points: np.ndarray
    """(N, 3) board face points of all poses (LiDAR frame, m)."""
    plane_normal: np.ndarray
    """(N, 3) and (N,): the board plane of each face point's pose in the camera frame, as the board z
    axis and offset: the signed distance of a camera-frame point ``x`` is ``normal . x + offset`` (m)."""
    plane_offset: np.ndarray
    edge_points: np.ndarray
    """(M, 3) edge points of all poses (LiDAR frame, m)."""
    edge_axes: np.ndarray
    """(M, 2, 3) and (M, 2): the board x and y axes of each edge point's pose in the camera frame and
    offsets, so that ``axes @ x + offset`` are a camera-frame point's board x, y (m)."""
    edge_offset: np.ndarray
    plane_pose: np.ndarray
    """(N,) and (M,): the pose index of each face and edge point."""
    edge_pose: np.ndarray

    @classmethod
    def build(cls, T_board_cameras: list[np.ndarray], found: list[BoardPoints]) -> _Stacked:
        T = np.array(T_board_cameras)
        plane_pose = np.repeat(np.arange(len(found)), [len(f.plane) for f in found])
        edge_pose = np.repeat(np.arange(len(found)), [len(f.edges) for f in found])
        return cls(np.vstack([f.plane for f in found]), T[plane_pose, 2, :3], T[plane_pose, 2, 3],
                   np.vstack([f.edges for f in found]), T[edge_pose, :2, :3], T[edge_pose, :2, 3],
                   plane_pose, edge_pose)

    def without_pose(self, k: int) -> _Stacked:
        plane, edge = self.plane_pose != k, self.edge_pose != k
        return _Stacked(self.plane_points[plane], self.plane_normal[plane], self.plane_offset[plane],
                        self.edge_points[edge], self.edge_axes[edge], self.edge_offset[edge],
                        self.plane_pose[plane], self.edge_pose[edge])

    def residuals(self, T_camera_lidar: np.ndarray, centre: np.ndarray, half: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Signed point-to-plane distances (N,) and edge-to-outline distances (M,) (m) at ``T_camera_lidar``."""
        plane_camera = transform_points(T_camera_lidar, self.plane_points)
        edge_camera = transform_points(T_camera_lidar, self.edge_points)
        plane = np.einsum("ni,ni->n", self.plane_normal, plane_camera) + self.plane_offset
        edge_xy = np.einsum("nij,nj->ni", self.edge_axes, edge_camera) + self.edge_offset
        return plane, outline_distance(edge_xy, centre, half)


def _edge_weight(T: np.ndarray, stacked: _Stacked, centre: np.ndarray, half: np.ndarray) -> float:
    """Inverse-variance weight of the edge residuals relative to the plane residuals at ``T``."""
    plane, edges = stacked.residuals(T, centre, half)
    mad_plane, mad_edges = (np.median(np.abs(r - np.median(r))) for r in (plane, edges))
    return float(mad_plane / mad_edges) if len(edges) and mad_edges > 0 else 1.0


def _solve(T_ref: np.ndarray, stacked: _Stacked, centre: np.ndarray, half: np.ndarray, edge_weight: float,
           settings: LidarCameraTargetSettings):
    """``least_squares`` about ``T_ref`` (parameters as :func:`~backend.core.transforms.params_between`, and with
    ``settings.solve_plate_margin`` a seventh: the plate margin's change (m), which widens ``half`` on every side).

    The Jacobian is analytic (a residual ``a . (R p + t) + c`` with ``R = R_ref Exp(w)`` has
    ``d/dt = a`` and ``d/dw = -((R^T a) x p)^T J_r(w)``; an edge residual moves by -1 per metre of margin):
    finite differences would cost six more residual evaluations per iteration, which the jackknife's
    re-solves multiply.
    """
    margin = settings.solve_plate_margin

    def residuals(p: np.ndarray) -> np.ndarray:
        plane, edges = stacked.residuals(apply_params(T_ref, p[:6]), centre, half + (p[6] if margin else 0.0))
        return np.concatenate([plane, edge_weight * edges])

    def jacobian(p: np.ndarray) -> np.ndarray:
        T = apply_params(T_ref, p[:6])
        R, J_r = T[:3, :3], right_jacobian(p[3:6])
        _, axis, sign = _nearest_side(np.einsum("nij,nj->ni", stacked.edge_axes,
                                                transform_points(T, stacked.edge_points)) + stacked.edge_offset,
                                      centre, half + (p[6] if margin else 0.0))
        across = edge_weight * sign[:, None] * stacked.edge_axes[np.arange(len(axis)), axis]
        rows = np.vstack([stacked.plane_normal, across])
        points = np.vstack([stacked.plane_points, stacked.edge_points])
        J = np.hstack([rows, -np.cross(rows @ R, points) @ J_r])
        if not margin:
            return J
        return np.hstack([J, np.r_[np.zeros(len(stacked.plane_points)), np.full(len(axis), -edge_weight)][:, None]])

    return least_squares(residuals, np.zeros(7 if margin else 6), jac=jacobian, loss=settings.loss,
                         f_scale=settings.loss_scale_m, max_nfev=settings.max_nfev, tr_solver="lsmr")


def _leave_one_out(T: np.ndarray, stacked: _Stacked, centre: np.ndarray, half: np.ndarray, edge_weight: float,
                   settings: LidarCameraTargetSettings, progress: ProgressCallback) -> np.ndarray:
    """(n, 6) the re-solves without each pose, as parameters about ``T`` (m along the camera's axes, rad about the
    LiDAR's)."""
    n = int(stacked.plane_pose.max()) + 1
    estimates = []
    for k in range(n):
        progress(0.8 + 0.15 * k / n, f"spread: solving without pose {k + 1} of {n}")
        estimates.append(_solve(T, stacked.without_pose(k), centre, half, edge_weight, settings).x[:6])
    return np.array(estimates)


def _with_moves(poses: list[PoseResiduals], without: np.ndarray, std_jacobian: np.ndarray) -> list[PoseResiduals]:
    """``poses`` with how far each one's leave-one-out re-solve (``without``, (n, 6) about the result) moves it."""
    ratio = np.abs(without) / np.maximum(std_jacobian, 1e-12)
    return [replace(pose, without_m=float(np.linalg.norm(move[:3])), without_deg=float(np.degrees(np.linalg.norm(
                move[3:]))), without_sigmas=float(np.max(np.where(np.isfinite(r), r, np.inf))))
            for pose, move, r in zip(poses, without, ratio, strict=True)]


def _lens_covariance(T: np.ndarray, lens_poses: list[np.ndarray], found: list[BoardPoints],
                     correlation: np.ndarray | None, centre: np.ndarray, half: np.ndarray, edge_weight: float,
                     settings: LidarCameraTargetSettings) -> np.ndarray:
    """(6, 6) the lens's share of the covariance: for each intrinsic parameter, the solve re-run (at the board points
    ``found`` of each pose, from ``T``) with every pose's board from PnP with that parameter moved by its 1-sigma
    (``lens_poses``: (P, 4, 4) per pose), the moves combined with the parameters' (P, P) ``correlation`` (identity
    when None): ``M C M^T`` with ``M`` the (6, P) moves."""
    n_parameters = len(lens_poses[0])
    moves = np.array([_solve(T, _Stacked.build([invert(poses[i]) for poses in lens_poses], found), centre, half,
                             edge_weight, settings).x[:6] for i in range(n_parameters)]).T
    correlation = np.eye(n_parameters) if correlation is None else np.asarray(correlation, float)
    return moves @ correlation @ moves.T


def _pose_names(observations: Sequence[TargetObservation]) -> list[str]:
    return [o.name or f"pose {i + 1}" for i, o in enumerate(observations)]


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2))) if len(values) else 0.0


def _fit_statistics(T: np.ndarray, stacked: _Stacked, centre: np.ndarray, half: np.ndarray, names: list[str]
                    ) -> tuple[dict[str, Any], list[PoseResiduals]]:
    """The result's ``residuals`` and each pose's fit at ``T``."""
    plane, edges = stacked.residuals(T, centre, half)
    d = np.abs(plane)
    poses = [PoseResiduals(name, int(np.sum(stacked.plane_pose == i)), int(np.sum(stacked.edge_pose == i)),
                           _rms(d[stacked.plane_pose == i]), _rms(edges[stacked.edge_pose == i]))
             for i, name in enumerate(names)]
    residuals = {"plane_rms_m": _rms(d), "plane_median_m": float(np.median(d)),
                 "plane_p95_m": float(np.percentile(d, 95)), "edge_rms_m": _rms(edges),
                 "per_pose_rms_m": [p.plane_rms_m for p in poses]}
    return residuals, poses


def solve_target(board: BoardSpec, observations: Sequence[TargetObservation], T_init: np.ndarray,
                 settings: LidarCameraTargetSettings | None = None,
                 progress: ProgressCallback = no_progress, skipped: Sequence[str] = (),
                 lens_correlation: np.ndarray | None = None) -> TransformResult:
    """Estimate ``T_camera_lidar`` (maps LiDAR points into the camera's optical frame, m) from board poses.

    ``observations`` pair each pose's camera board pose with its LiDAR cloud; ``T_init`` is the
    initial ``T_camera_lidar`` (it places the first round's search region: its error at the
    board must stay within ``settings.region_margins_m[0]``). A pose whose board is not found in its
    cloud is skipped, named in the warnings and ``diagnostics["skipped"]``, with those the caller already
    skipped (``skipped``: one message per pose, naming it; the board not found in its image, say); so is one
    whose board is lost in a later round, about the refined estimate (the first round's wide region took
    something else for it: the person holding it, on the real VLP-16 set with the board's points removed). Raises
    :class:`InputError` for fewer than :data:`MIN_POSES` usable poses (with the count and why each other
    pose was skipped), a bad cloud or transform, and a degenerate set of board normals. A solve that diverges or
    ends with a point-to-plane RMS above ``settings.max_plane_rms_m`` is returned with ``converged=False`` and a
    warning: the caller must not accept it.

    Returns a :class:`~backend.core.result.TransformResult` (kind ``lidar_camera``, method ``target``, parent
    ``camera``, child ``lidar``): ``T_parent_child`` is ``T_camera_lidar``; its covariance holds the reported
    (larger-per-parameter) sigmas with the Jacobian's correlations. ``residuals``: ``plane_rms_m``,
    ``plane_median_m``, ``plane_p95_m`` (absolute point-to-plane distances), ``edge_rms_m`` (edge points to the
    plate outline, in the board plane) and ``per_pose_rms_m`` (point-to-plane RMS of each pose), all in m.
    ``diagnostics``: ``std_jacobian`` (6,) from ``sigma^2 (J^T J)^-1``, ``std_spread`` (6,) of the
    leave-one-pose-out jackknife or None and ``std_lens`` (6,), the lens's share (:func:`_lens_covariance`, added to
    the covariance) when every pose carries ``T_camera_board_lens`` (``lens_correlation``: the intrinsic
    parameters' correlation), else None (m, m, m, rad, rad, rad; None where undetermined), ``T_init``,
    ``iterations`` (residual evaluations over all rounds), ``rounds`` (segmentation + solve rounds run),
    ``poses`` (each solved pose's :class:`PoseResiduals`, in input order, with how far the solve without it moves
    the result) and ``skipped`` (why each other pose was skipped, naming it).
    """
    settings = settings or LidarCameraTargetSettings()
    started = time.perf_counter()
    skipped = list(skipped)
    total = len(observations) + len(skipped)
    _check_pose_count(len(observations), total, skipped)
    names = _pose_names(observations)
    T_camera_boards = [check_transform(o.T_camera_board, f"{name}: T_camera_board")[0]
                       for o, name in zip(observations, names, strict=True)]
    clouds = [check_cloud(o.points_lidar, f"{name}: cloud")[0] for o, name in zip(observations, names, strict=True)]
    lens_poses = [o.T_camera_board_lens for o in observations]
    T_init, _ = check_transform(T_init, "T_init")
    margin_m = settings.plate_margin_m
    centre, half = plate_centre_and_half_size(board, margin_m)
    rng = np.random.default_rng(settings.seed)

    T, stacked, result, warnings, iterations, converged = T_init, None, None, [], 0, True
    edge_weight = 1.0
    for round_index, margin in enumerate(settings.region_margins_m):
        progress(0.8 * round_index / len(settings.region_margins_m),
                 f"round {round_index + 1}: finding the board in {len(clouds)} clouds ({margin} m region)")
        at_margin = replace(settings, plate_margin_m=margin_m)
        found, lost = _find_boards(clouds, T_camera_boards, T, board, margin, at_margin, rng, names)
        kept = [i for i, points in enumerate(found) if points is not None]
        if round_index > 0:  # the first round took something else for the board there (a person behind it, a wall)
            lost = [f"{message} (in round {round_index + 1}, about the refined estimate: in round 1 something else "
                    "near it was taken for the board)" for message in lost]
        skipped += lost
        _check_pose_count(len(kept), total, skipped)
        names, T_camera_boards, clouds, found, lens_poses = (
            [items[i] for i in kept] for items in (names, T_camera_boards, clouds, found, lens_poses))
        if round_index == 0:
            check_normals(np.array([T[:3, 2] for T in T_camera_boards]), settings.min_normal_eigenvalue)
        stacked = _Stacked.build([invert(T_cb) for T_cb in T_camera_boards], found)
        if settings.edge_weight is not None:
            edge_weight = settings.edge_weight
        elif round_index > 0:
            edge_weight = _edge_weight(T, stacked, centre, half)
        result = _solve(T, stacked, centre, half, edge_weight, settings)
        iterations += int(result.nfev)
        T = apply_params(T, result.x[:6])
        if settings.solve_plate_margin:
            margin_m += float(result.x[6])
            half = plate_centre_and_half_size(board, margin_m)[1]
        if result.status <= 0:
            warnings.append(f"round {round_index + 1}: least squares stopped without converging "
                            f"({result.message}); not accepted")
            converged = False
            break

    assert stacked is not None and result is not None  # region_margins_m is not empty
    warnings[:0] = [f"{message}; skipped" for message in skipped]
    # The covariance is taken at the last linearisation, about the final estimate (the last step is tiny).
    cov_all = jacobian_covariance(result, len(result.x))
    cov_j = cov_all[:6, :6]
    std_spread = None
    residuals, poses = _fit_statistics(T, stacked, centre, half, names)
    if residuals["plane_rms_m"] > settings.max_plane_rms_m:
        warnings.append(f"poor fit: point-to-plane RMS {residuals['plane_rms_m'] * 1000:.1f} mm > "
                        f"{settings.max_plane_rms_m * 1000:.1f} mm; not accepted")
        converged = False
    if settings.spread and converged:
        without = _leave_one_out(T, stacked, centre, half, edge_weight, settings, progress)
        std_spread = jackknife_std(without)
        poses = _with_moves(poses, without, sigmas(cov_j))
    cov_lens = None
    if converged and all(poses_p is not None for poses_p in lens_poses):
        progress(0.97, "carrying the lens's uncertainty into the board poses")
        cov_lens = _lens_covariance(T, lens_poses, found, lens_correlation, centre, half, edge_weight, settings)
    progress(1.0, "done")
    covariance = widen_covariance(cov_j, std_spread)
    return TransformResult(
        kind="lidar_camera", method="target", parent="camera", child="lidar",
        T_parent_child=T,
        covariance=covariance if cov_lens is None else covariance + cov_lens,
        residuals=residuals,
        diagnostics={"std_jacobian": finite_or_none(sigmas(cov_j)),
                     "std_spread": finite_or_none(std_spread),
                     "std_lens": None if cov_lens is None else finite_or_none(sigmas(cov_lens)),
                     "T_init": T_init.tolist(), "iterations": iterations,
                     "rounds": round_index + 1, "poses": [p.to_record() for p in poses], "skipped": skipped,
                     "plate_margin_m": margin_m,
                     "plate_margin_std_m": finite_or_none(sigmas(cov_all)[6:])[0] if settings.solve_plate_margin
                     else None},
        settings=asdict(settings),
        converged=converged,
        warnings=warnings,
        seconds=time.perf_counter() - started,
    )
