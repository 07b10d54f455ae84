"""LiDAR-to-camera from V-shaped 3D targets: two plates at a known angle, with markers on each face.

The spec and frames are :class:`~backend.core.v_target.VTarget`'s. Per placement (one image and its cloud):

1. **In the image**, the target's pose ``T_camera_target`` from every marker corner found on either face: PnP on
   the undistorted corners (the two faces make it a 3D target, so one image pins it well), refined in pixels
   through the camera's own model (:func:`camera_v_target_pose`).
2. **In the cloud**, each face's points (:func:`face_points`): the points near the face as the current estimate
   puts it, split between the two faces by which plane is nearer, then a RANSAC plane per face facing the way the
   camera says the face faces (:func:`~backend.calib.lidar_camera.target.fit_plane`), so the floor, a wall or
   the stand never win. A face with fewer than :data:`MIN_FACE_POINTS` points is not seen and its placement is
   left out, saying so. The two planes' intersection is the ridge, reported against the camera's.
3. **The extrinsic**: least squares over the six parameters of ``T_camera_lidar`` of every face point's distance
   to its face's plane as the camera sees it, over all placements (robust loss), in two rounds: the second finds
   the faces again about the first round's estimate with a tight region.

The plates fix the LiDAR along their normals only: when every placement's ridge points the same way (upright
targets all), the translation along the ridges is undetermined, and the solve refuses, asking to lean some
targets (:func:`~backend.calib.lidar_camera.target.check_normals`). Sigma is the Jacobian's, widened to the
leave-one-placement-out spread (the camera's pose error moves a placement's points together, which the
Jacobian cannot see); the verdict (:func:`~backend.calib.lidar_camera.checks.judge`) takes that spread as the
cross-check between placements, as the board target method does.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from backend.calib.lidar_camera.checks import judge
from backend.calib.lidar_camera.target import LidarCameraTargetSettings, check_normals, fit_plane
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.markers import detect_markers
from backend.core.result import TransformResult, jackknife_std, jacobian_covariance, widen_covariance
from backend.core.schur_lm import levenberg_marquardt, shared_covariance
from backend.core.transforms import (
    apply_params,
    apply_params_many,
    from_rvec_tvec,
    invert,
    params_between,
    right_jacobian,
    transform_points,
)
from backend.core.v_target import VTarget

MIN_MARKERS = 2
"""Fewest of the target's markers in an image for its pose (8 corners)."""
MIN_FACE_POINTS = 30
"""Fewest points on a face for it to count as seen by the LiDAR."""
MAX_FACE_POINTS = 800
"""A face's points beyond this many are thinned at random before the solve: a near face holds 15,000 points of a
Livox, whose mean the camera's pose error outweighs long before that."""
MIN_PLACEMENTS = 2
"""Fewest placements with both faces seen: one V fixes the LiDAR only across its ridge."""
REGION_MARGINS_M = (0.3, 0.05)
"""Margin around each plate of the region searched for its points, one round each (m): the first covers the
mounting guess's error at the target (10 cm and 3 deg at 3 m); the second, about the first round's estimate,
keeps the stand and the floor just below the plates out."""
PLANE_THRESHOLD_M = 0.05
"""Largest distance of a face point from its RANSAC plane (m): about 3 range-noise sigmas of a Livox or a VLP-16."""
MIN_SIGMA_M = 0.002
"""The smallest range noise (m) a face point is taken to have, whatever the residuals say."""
EXACT_POSE_COVARIANCE = np.diag([1e-6**2] * 3 + [1e-8**2] * 3)
"""The prior of a camera pose given without a covariance: held where it is (1 um, 0.01 urad)."""
MIN_NORMAL_EIGENVALUE = 1e-2
"""Smallest eigenvalue of the faces' normal scatter for the translation to be determined (about 6 deg of spread)."""


@dataclass
class VTargetPlacement:
    """One placement of the target, seen by both sensors."""

    name: str
    T_camera_target: np.ndarray
    """4x4 the target's pose in the camera's optical frame (m), from its markers."""
    points_lidar: np.ndarray
    """(N, 3) the cloud in the LiDAR frame (m)."""
    markers_per_face: tuple[int, int] = (0, 0)
    """How many of each face's markers the image showed."""
    image_rms_px: float = float("nan")
    """RMS of the marker corners' reprojection at ``T_camera_target`` (px)."""
    cov_camera_target: np.ndarray | None = None
    """6x6 covariance of ``T_camera_target`` (:func:`~backend.core.transforms.apply_params`' parameters: m, rad),
    carried into the result's sigma; None: the camera's pose is taken as exact."""
    marker_scale: float = 1.0
    """The markers' size in the image against the spec's, fitted with the pose (:func:`camera_v_target_pose`)."""


def camera_v_target_pose(image: np.ndarray, camera: CameraIntrinsics, target: VTarget, name: str,
                         points_lidar: np.ndarray) -> VTargetPlacement:
    """The placement of the target whose image is ``image`` and cloud ``points_lidar`` (LiDAR frame, m):
    ``T_camera_target`` from the target's markers in the image, with its covariance (the corners' reprojection
    variance through the Jacobian); :class:`InputError` naming ``name`` when fewer than :data:`MIN_MARKERS`
    are found.

    Each marker's corners are fitted about its centre with one scale for all the image's markers
    (``marker_scale``, a nuisance): the corner detector pulls a black square's corners a quarter of a pixel
    inwards and printer's ink spreads, both of which shrink or grow every marker alike. Left in, on the simulated
    rig the markers came out 1-3 % small and every target 6 mm too far on average; the layout of the markers on
    the plates fixes the pose's scale, their own size need not."""
    found = detect_markers(image, target.dictionary)
    ids, counts = np.unique(found.ids, return_counts=True)
    keep = (target.face_of(found.ids) >= 0) & ~np.isin(found.ids, ids[counts > 1])
    if keep.sum() < MIN_MARKERS:
        raise InputError(f"{name}: {int(keep.sum())} of the V-target's markers ({target.dictionary}, ids 0 to "
                         f"{len(target.marker_ids) - 1}) found; its pose needs {MIN_MARKERS} or more", name)
    marker_ids = found.ids[keep]
    corners = target.marker_corners[marker_ids]
    centres = corners.mean(axis=1, keepdims=True)
    pixels = found.corners_px[keep].reshape(-1, 2)
    ok, rvec, tvec = cv2.solvePnP(corners.reshape(-1, 3), camera.undistort_points(pixels).reshape(-1, 1, 2),
                                  np.eye(3), None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise InputError(f"{name}: PnP failed on the V-target's {len(pixels)} marker corners", name)
    T_start = from_rvec_tvec(rvec, tvec)

    def residuals(p: np.ndarray) -> np.ndarray:
        object_points = (centres + (1 + p[6]) * (corners - centres)).reshape(-1, 3)
        return (camera.project(transform_points(apply_params(T_start, p[:6]), object_points)) - pixels).ravel()

    fit = least_squares(residuals, np.zeros(7), method="lm", x_scale=np.r_[0.01, 0.01, 0.01, 1e-3, 1e-3, 1e-3, 0.01])
    faces = target.face_of(marker_ids)
    return VTargetPlacement(name, apply_params(T_start, fit.x[:6]), np.asarray(points_lidar, float),
                            (int(np.sum(faces == 0)), int(np.sum(faces == 1))), float(np.sqrt(np.mean(fit.fun**2) * 2)),
                            jacobian_covariance(fit, 7)[:6, :6], 1.0 + float(fit.x[6]))


def face_points(points_lidar: np.ndarray, T_lidar_target: np.ndarray, target: VTarget, margin_m: float,
                rng: np.random.Generator) -> list[np.ndarray]:
    """Each face's points (LiDAR frame, m) in a cloud, the target placed at ``T_lidar_target`` by the current
    estimate: the points within ``margin_m`` of a plate (in its plane, and along its normal beyond the RANSAC
    threshold), each given to the nearer plate, then the RANSAC plane's inliers (an empty array for a face whose
    plane is not found, or whose back the LiDAR sees: a plate's back is its thickness off the printed face's plane),
    thinned to :data:`MAX_FACE_POINTS`."""
    T_target_lidar = invert(T_lidar_target)
    points_target = transform_points(T_target_lidar, points_lidar[:, :3])
    depth, inside = [], []
    for face in range(2):
        T_face_target = invert(target.T_target_face[face])
        local = transform_points(T_face_target, points_target)
        depth.append(np.abs(local[:, 2]))
        inside.append((local[:, 0] > -margin_m) & (local[:, 0] < target.width_m + margin_m)
                      & (local[:, 1] > -margin_m) & (local[:, 1] < target.height_m + margin_m)
                      & (depth[face] < margin_m + PLANE_THRESHOLD_M))
    nearer = np.argmin(np.column_stack(depth), axis=1)
    settings = LidarCameraTargetSettings(plane_threshold_m=PLANE_THRESHOLD_M, max_normal_angle_deg=15.0)
    found = []
    for face in range(2):
        region = points_lidar[inside[face] & (nearer == face), :3]
        expected_normal = T_lidar_target[:3, :3] @ target.face_planes[face, :3]
        facing = len(region) and float(np.median(region @ expected_normal)) < 0  # else the LiDAR sees its back
        fit = fit_plane(region, expected_normal, settings, rng) if facing and len(region) >= MIN_FACE_POINTS else None
        inliers = region[fit.inliers] if fit is not None else np.zeros((0, 3))
        if len(inliers) > MAX_FACE_POINTS:
            inliers = inliers[np.sort(rng.choice(len(inliers), MAX_FACE_POINTS, replace=False))]
        found.append(inliers)
    return found


def _face_planes_camera(target: VTarget, T_camera_target: np.ndarray) -> np.ndarray:
    """(2, 4) the faces' planes ``[n, d]`` in the camera frame (``n . x + d = 0``, m)."""
    normals = target.face_planes[:, :3] @ T_camera_target[:3, :3].T
    offsets = target.face_planes[:, 3] - np.einsum("fi,i->f", normals, T_camera_target[:3, 3])
    return np.column_stack([normals, offsets])


@dataclass
class _Problem:
    """All placements' face points stacked, with each placement's camera pose and its prior, so the joint solve's
    residuals are vectorised over points."""

    points: np.ndarray
    """(N, 3) face points of every placement (LiDAR frame, m)."""
    owner: np.ndarray
    """(N,) the placement of each point."""
    planes: np.ndarray
    """(N, 4) the target-frame plane ``[n, d]`` of each point's face."""
    T_camera_targets: np.ndarray
    """(K, 4, 4) each placement's target pose from its markers."""
    prior_roots: np.ndarray
    """(K, 6, 6) ``L`` with ``L^T L`` the inverse covariance of each pose: its prior residuals are ``L @ delta``."""

    @classmethod
    def build(cls, target: VTarget, placements: Sequence[VTargetPlacement], faces: Sequence[list[np.ndarray]]
              ) -> _Problem:
        points, owner, face_of = [], [], []
        for k, found in enumerate(faces):
            for face, face_pts in enumerate(found):
                points.append(face_pts)
                owner.append(np.full(len(face_pts), k))
                face_of.append(np.full(len(face_pts), face))
        roots = [np.linalg.cholesky(np.linalg.inv(EXACT_POSE_COVARIANCE if p.cov_camera_target is None
                                                  else p.cov_camera_target)).T for p in placements]
        return cls(np.concatenate(points), np.concatenate(owner), target.face_planes[np.concatenate(face_of)],
                   np.array([p.T_camera_target for p in placements]), np.array(roots))

    def without(self, k: int) -> _Problem:
        """The problem without placement ``k`` (the later ones renumbered)."""
        keep = self.owner != k
        rest = np.delete(np.arange(len(self.T_camera_targets)), k)
        return _Problem(self.points[keep], np.searchsorted(rest, self.owner[keep]), self.planes[keep],
                        self.T_camera_targets[rest], self.prior_roots[rest])

    def _state(self, z: np.ndarray, T_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``T_camera_lidar``, every ``T_camera_target`` and every point in its target's frame, at ``z``."""
        T_camera_lidar = apply_params(T_ref, z[:6])
        T_camera_targets = apply_params_many(self.T_camera_targets, z[6:].reshape(-1, 6))
        T_target_cameras = invert(T_camera_targets)
        camera_points = transform_points(T_camera_lidar, self.points)
        target_points = (np.einsum("nij,nj->ni", T_target_cameras[self.owner, :3, :3], camera_points)
                         + T_target_cameras[self.owner, :3, 3])
        return T_camera_lidar, T_camera_targets, target_points

    def _blocks(self, z: np.ndarray, T_ref: np.ndarray, sigma_m: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At ``z`` (``T_camera_lidar``'s step about ``T_ref``, then every pose's step; m, rad): each point's
        distance to its face in ``sigma_m``, and its analytic derivatives by ``T_camera_lidar`` (N, 6) and by its own
        pose (N, 6). For a point ``p`` (LiDAR), ``q`` (target frame) and its face's normal ``n``: by
        ``T_camera_lidar``'s translation ``R_camera_target n``, by its rotation ``p x (R_camera_lidar^T
        R_camera_target n)``; by its pose's translation ``-R_camera_target n``, by its rotation ``n x q``;
        rotations through the right Jacobian of the step taken (``apply_params`` turns a rotation on the right)."""
        steps = z[6:].reshape(-1, 6)
        T_camera_lidar, T_camera_targets, target_points = self._state(z, T_ref)
        normals = self.planes[:, :3]
        distance = np.einsum("ni,ni->n", target_points, normals) + self.planes[:, 3]
        n_camera = np.einsum("nij,nj->ni", T_camera_targets[self.owner, :3, :3], normals)
        n_lidar = n_camera @ T_camera_lidar[:3, :3]
        by_extrinsic = np.column_stack([n_camera, np.cross(self.points, n_lidar) @ right_jacobian(z[3:6])])
        right = np.array([right_jacobian(step[3:]) for step in steps])
        by_pose = np.column_stack([-n_camera, np.einsum("ni,nij->nj", np.cross(normals, target_points),
                                                        right[self.owner])])
        return distance / sigma_m, by_extrinsic / sigma_m, by_pose / sigma_m

    def evaluate(self, z: np.ndarray, T_ref: np.ndarray, sigma_m: float
                 ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """Per placement: its points' residuals then its pose's prior residuals (``L @ step``), and their Jacobians
        by ``T_camera_lidar`` and by its pose, as :func:`~backend.core.schur_lm.levenberg_marquardt` takes them."""
        return self._per_placement(z, *self._blocks(z, T_ref, sigma_m))

    def _per_placement(self, z: np.ndarray, distance: np.ndarray, by_extrinsic: np.ndarray, by_pose: np.ndarray
                       ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        bounds = np.flatnonzero(np.diff(self.owner)) + 1
        steps = z[6:].reshape(-1, 6)
        residuals, extrinsic, pose = [], [], []
        for k, (r, a, b) in enumerate(zip(np.split(distance, bounds), np.split(by_extrinsic, bounds),
                                          np.split(by_pose, bounds), strict=True)):
            residuals.append(np.concatenate([r, self.prior_roots[k] @ steps[k]]))
            extrinsic.append(np.vstack([a, np.zeros((6, 6))]))
            pose.append(np.vstack([b, self.prior_roots[k]]))
        return residuals, extrinsic, pose

    def solve(self, T_ref: np.ndarray, sigma_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The joint least squares from ``T_ref``: ``T_camera_lidar``, its 6x6 covariance (the camera's pose errors
        in it, through their priors) and each point's distance to its face at the solution (m)."""
        count = len(self.T_camera_targets)
        z = levenberg_marquardt(lambda x: self.evaluate(x, T_ref, sigma_m), np.zeros(6 + 6 * count), 6)
        distance, by_extrinsic, by_pose = self._blocks(z, T_ref, sigma_m)
        _, extrinsic, pose = self._per_placement(z, distance, by_extrinsic, by_pose)
        return apply_params(T_ref, z[:6]), shared_covariance(extrinsic, pose), distance * sigma_m


def _ridge_offset(target: VTarget, placement: VTargetPlacement, found: list[np.ndarray],
                  T_camera_lidar: np.ndarray) -> float | None:
    """How far the ridge of the cloud's two fitted planes passes from the camera's ridge, at the ridge's midpoint
    (m, mapped by ``T_camera_lidar``); None when a face has too few points."""
    if min(len(f) for f in found) < MIN_FACE_POINTS:
        return None
    T_target_lidar = invert(placement.T_camera_target) @ T_camera_lidar
    planes = []
    for face_pts in found:
        local = transform_points(T_target_lidar, face_pts)
        centroid = local.mean(axis=0)
        normal = np.linalg.svd(local - centroid, full_matrices=False)[2][2]
        planes.append((normal, -normal @ centroid))
    (n0, d0), (n1, d1) = planes
    # the point of both planes nearest the target's origin (the camera's ridge midpoint): min |x|^2 s.t. both
    A = np.array([n0, n1])
    midpoint = -A.T @ np.linalg.solve(A @ A.T, np.array([d0, d1]))
    direction = np.cross(n0, n1)
    direction /= np.linalg.norm(direction)
    offset = midpoint - (midpoint @ direction) * direction
    return float(np.linalg.norm(offset[[0, 2]]))


def solve_v_target(target: VTarget, placements: Sequence[VTargetPlacement], T_init: np.ndarray,
                   camera_frame: str = "camera", lidar_frame: str = "lidar", seed: int = 0) -> TransformResult:
    """``T_camera_lidar`` from V-target placements, starting at the mounting guess ``T_init``; judged.

    A placement whose cloud shows fewer than :data:`MIN_FACE_POINTS` on a face is left out with a warning naming
    it; :class:`InputError` when fewer than :data:`MIN_PLACEMENTS` remain or the faces' normals do not determine
    the translation."""
    started = time.perf_counter()
    rng = np.random.default_rng(seed)
    T = np.asarray(T_init, float)
    warnings: list[str] = []
    sigma_m = PLANE_THRESHOLD_M / 3
    for round_index, margin_m in enumerate(REGION_MARGINS_M):
        faces = [face_points(p.points_lidar, invert(T) @ p.T_camera_target, target, margin_m, rng)
                 for p in placements]
        seen = [min(len(f) for f in found) >= MIN_FACE_POINTS for found in faces]
        if round_index == 0:
            warnings = [_one_face_message(p, found) for p, found, ok in zip(placements, faces, seen, strict=True)
                        if not ok]
        if sum(seen) < MIN_PLACEMENTS:
            raise InputError(f"{sum(seen)} of {len(placements)} placements show both faces of the V-target in the "
                             f"cloud; at least {MIN_PLACEMENTS} are needed. " + " ".join(warnings[:3]),
                             placements[seen.index(False)].name if False in seen else "placements")
        used = [p for p, ok in zip(placements, seen, strict=True) if ok]
        faces = [found for found, ok in zip(faces, seen, strict=True) if ok]
        if round_index == 0:
            check_normals(np.concatenate([_face_planes_camera(target, p.T_camera_target)[:, :3] for p in used]),
                          MIN_NORMAL_EIGENVALUE, "lean or lay some of the targets so that their ridges point "
                          "different ways (the plates fix the LiDAR only across their ridges)")
        problem = _Problem.build(target, used, faces)
        T, covariance, distances_m = problem.solve(T, sigma_m)
        sigma_m = max(float(1.4826 * np.median(np.abs(distances_m))), MIN_SIGMA_M)  # the next round's noise
    spread = None
    if len(used) >= 3:
        spread = jackknife_std(np.array([params_between(T, problem.without(k).solve(T, sigma_m)[0])
                                         for k in range(len(used))]))
    per_placement = {p.name: {"face_points": [len(f) for f in found], "markers_per_face": list(p.markers_per_face),
                              "image_rms_px": p.image_rms_px, "marker_scale": p.marker_scale,
                              "plane_rms_m": float(np.sqrt(np.mean(distances_m[problem.owner == k] ** 2))),
                              "ridge_offset_m": _ridge_offset(target, p, found, T)}
                     for k, (p, found) in enumerate(zip(used, faces, strict=True))}
    result = TransformResult(
        kind="lidar_camera", method="vtarget", parent=camera_frame, child=lidar_frame, T_parent_child=T,
        covariance=widen_covariance(covariance, spread),
        residuals={"plane_rmse_m": float(np.sqrt(np.mean(distances_m**2))), "points": len(distances_m),
                   "placements": len(used),
                   "image_rms_px": float(np.sqrt(np.mean([p.image_rms_px**2 for p in used])))},
        diagnostics={"placements": per_placement, "std_jacobian": np.sqrt(np.diag(covariance)).tolist(),
                     "std_spread": None if spread is None else spread.tolist(), "point_sigma_m": sigma_m},
        settings={"target": str(target)}, warnings=warnings)
    judge(result)
    result.seconds = time.perf_counter() - started
    return result


def _one_face_message(placement: VTargetPlacement, found: list[np.ndarray]) -> str:
    """Why ``placement`` is left out: the face(s) the cloud does not show."""
    missing = [face for face, face_pts in enumerate(found) if len(face_pts) < MIN_FACE_POINTS]
    if len(missing) == 2:
        return (f"{placement.name}: the cloud shows neither face of the V-target near where the camera sees it "
                "(is the mounting guess within 10 cm and 3 deg?); left out")
    face = missing[0]
    return (f"{placement.name}: only one face of the V-target is seen in the cloud (face {1 - face}; face {face} "
            f"has {len(found[face])} points, {MIN_FACE_POINTS} needed); left out: turn the target so the LiDAR "
            "sees both faces")
