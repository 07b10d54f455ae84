#!/usr/bin/env python
"""Disaster-response rig benchmark: the wall test field's intrinsics and the V-target extrinsic on the simulated
Blackfly and Livox, each beside its in-run reference on the same input.

- ``test_field``: 12 rendered wall images (40 surveyed markers, six positions straight and turned 90 deg). Ours: the
  photogrammetric bundle adjustment on the marker centres found again through the lens; the reference: OpenCV's
  ``calibrateCamera`` (five coefficients, started from the flattened field, as OpenCV cannot start a non-planar
  target itself) on the same centres. Figures: RMS of both (the paper's 0.392 px beside them), the principal
  distance's error against the truth, the K1-K2, K2-K3, K1-K3 correlations beside the paper's, and the solve time.
- ``exterior``: the same 12 images posed in the wall's frame through our photogrammetric solve, its sigma carried
  (:func:`~backend.calib.test_field.service.resect_image`); the reference: OpenCV's ``solvePnP`` (iterative) on the
  same marker centres, undistorted through the same lens (OpenCV has no photogrammetric model). Figures: each one's
  error against the truth (median, largest), our sigma and the largest error in sigmas per axis, and the time per
  image from the same centres (ours: RANSAC, the refinement, the two halves and the lens's share).
- ``v_target``: 18 placements of the 100 x 60 cm V-target. Ours: the joint solve with each camera pose held by its
  prior (Schur-complement Levenberg-Marquardt); the in-run baseline: the same point-to-plane problem with the
  camera poses fixed (SciPy's ``least_squares``, the solve before the priors). Figures: each one's error against
  the truth (mm, deg, beside the paper's 3-5 mm) and its time, and the ratio of the times. No library solves
  V-targets, so there is no outside reference.

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/disaster_response.py
"""

import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from bench_util import log, median_time, pose_error
from scipy.optimize import least_squares

from backend.calib.intrinsics.solver import IntrinsicsSettings, View, _calibrate, calibrate_intrinsics, planar_start
from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
from backend.calib.lidar_camera.service import PairData, solve_pairs
from backend.calib.lidar_camera.v_target import REGION_MARGINS_M, _Problem, camera_v_target_pose, face_points
from backend.calib.test_field.detection import detect_test_field
from backend.calib.test_field.exterior import resect
from backend.calib.test_field.service import resect_image
from backend.core.test_field import TestField
from backend.core.transforms import apply_params, invert, make_T, transform_error, transform_points
from backend.core.v_target import VTarget
from backend.sim.disaster_response import MEASURED_MOUNT, T_CAMERA_LIVOX_TRUE, V_TARGET, v_target_shots
from backend.sim.marker_targets import (
    disaster_response_camera,
    field_views,
    render_test_field_image,
    simulated_test_field,
)

PAPER = {"rms_px": 0.392, "K1-K2": -0.964, "K2-K3": -0.983, "K1-K3": 0.907, "v_target_mm": "3-5", "v_target_px": 0.2}
CAMERA = disaster_response_camera()
SIZE = (CAMERA.width, CAMERA.height)


def test_field() -> tuple[dict, dict]:
    folder = Path(tempfile.mkdtemp())
    spec, _ = simulated_test_field(folder)
    field = TestField.parse(spec)
    views, images = [], []
    for k, T_camera_wall in enumerate(field_views()):
        image = render_test_field_image(CAMERA, field, T_camera_wall, np.random.default_rng(k))
        views.append(View(f"wall_{k:02d}", detect_test_field(image, field, f"wall_{k:02d}").detection))
        images.append(image)
    log(f"test field: {len(views)} views")
    settings = IntrinsicsSettings(model="photogrammetric", pixel_size_um=4.8)
    ours = calibrate_intrinsics(views, field, SIZE, settings)
    names, matrix = ours.correlation_names, np.array(ours.correlation)
    correlations = {pair: round(float(matrix[names.index(pair[:2]), names.index(pair[3:])]), 3)
                    for pair in ("K1-K2", "K2-K3", "K1-K3")}
    object_points = [field.object_points[v.detection.ids] for v in views]
    image_points = [v.detection.corners_px.astype(np.float32) for v in views]
    K_start = planar_start(views, field, SIZE)

    def opencv():
        return cv2.calibrateCamera(object_points, image_points, SIZE, K_start.copy(), None,
                                   flags=cv2.CALIB_USE_INTRINSIC_GUESS)

    rms, K, *_ = opencv()
    return exterior(ours, field, images), {
            "views": len(views), "rms_px": {"ours": ours.rms_px, "opencv_5": rms, "paper": PAPER["rms_px"]},
            "c_error_px": {"ours": float(ours.camera.K[0, 0] - CAMERA.K[0, 0]),
                           "opencv_5": float(np.mean(np.diag(K)[:2]) - CAMERA.K[0, 0])},
            "correlations": {"ours": correlations, "paper": {k: PAPER[k] for k in correlations}},
            "verdict": ours.verdict.level,
            "solve_s": {"ours": median_time(lambda: _calibrate(views, field, SIZE, settings)),
                        "opencv_5": median_time(opencv)}}


def exterior(solved, field: TestField, images: list[np.ndarray]) -> dict:
    lens = LensUncertainty.from_record(solved.to_record())
    camera = solved.camera
    ours, reference, sigmas, worst_z = [], [], [], []
    for image, T_camera_wall in zip(images, field_views(), strict=True):
        T_true = invert(T_camera_wall)
        result = resect_image(image, camera, field, "wall", lens)
        ours.append(pose_error(result.T_parent_child, T_true))
        trans_m, rot_deg = transform_error(result.T_parent_child, T_true)
        worst_z.append(float(max(np.max(np.abs(trans_m) / result.std["trans_m"]),
                                 np.max(np.abs(rot_deg) / result.std["rot_deg"]))))
        sigmas.append((1000 * float(np.linalg.norm(result.std["trans_m"])),
                       float(np.linalg.norm(result.std["rot_deg"]))))
        detection = detect_test_field(image, field, "wall", camera).detection
        normalised = camera.undistort_points(detection.corners_px).reshape(-1, 1, 2)
        _, rvec, tvec = cv2.solvePnP(field.centres_m[detection.ids].reshape(-1, 1, 3), normalised, np.eye(3), None)
        reference.append(pose_error(invert(make_T(cv2.Rodrigues(rvec)[0], tvec.ravel())), T_true))
    ours_a, reference_a, sigma_a = np.array(ours), np.array(reference), np.array(sigmas)
    ours_s = median_time(lambda: resect(camera, field, detection, "wall", lens))  # both from the same centres
    opencv_s = median_time(lambda: cv2.solvePnP(field.centres_m[detection.ids].reshape(-1, 1, 3),
                                                camera.undistort_points(detection.corners_px).reshape(-1, 1, 2),
                                                np.eye(3), None))

    def summary(errors: np.ndarray) -> dict:
        return {"median_mm": float(np.median(errors[:, 0])), "max_mm": float(errors[:, 0].max()),
                "median_deg": float(np.median(errors[:, 1])), "max_deg": float(errors[:, 1].max())}

    return {"images": len(images), "error": {"ours": summary(ours_a), "opencv_pnp": summary(reference_a)},
            "sigma": {"median_mm": float(np.median(sigma_a[:, 0])), "median_deg": float(np.median(sigma_a[:, 1]))},
            "largest_error_in_sigmas": max(worst_z),
            "per_image_s": {"ours": ours_s, "opencv_pnp": opencv_s}, "ratio": ours_s / opencv_s}


def _fixed_poses_solve(target: VTarget, placements: list, T_init: np.ndarray) -> np.ndarray:
    """The baseline: point-to-plane over ``T_camera_lidar`` alone, each camera pose taken as exact (SciPy)."""
    T = T_init
    rng = np.random.default_rng(0)
    for margin_m in REGION_MARGINS_M:
        faces = [face_points(p.points_lidar, invert(T) @ p.T_camera_target, target, margin_m, rng) for p in placements]
        kept = [(p, f) for p, f in zip(placements, faces, strict=True) if min(map(len, f)) >= 30]
        problem = _Problem.build(target, [p for p, _ in kept], [f for _, f in kept])

        def residuals(x, problem=problem, T_ref=T):
            return problem._blocks(np.r_[x, np.zeros(6 * len(problem.T_camera_targets))], T_ref, 1.0)[0]

        T = apply_params(T, least_squares(residuals, np.zeros(6), loss="soft_l1", f_scale=0.03).x)
    return T


def v_target() -> dict:
    shots = v_target_shots(CAMERA)
    target = VTarget.parse(V_TARGET)
    pairs = [PairData(s.name, s.name, s.image, s.points_lidar, s.intensity) for s in shots]
    log(f"V-target: {len(pairs)} placements")
    result = solve_pairs(CAMERA, target, pairs, MEASURED_MOUNT, method="vtarget")
    placements = [camera_v_target_pose(s.image, CAMERA, target, s.name, s.points_lidar) for s in shots]
    T_fixed = _fixed_poses_solve(target, placements, MEASURED_MOUNT)
    ours_s = median_time(lambda: solve_pairs(CAMERA, target, pairs, MEASURED_MOUNT, method="vtarget"), 2)
    fixed_s = median_time(lambda: _fixed_poses_solve(target, placements, MEASURED_MOUNT), 2)
    corners_px = [np.sqrt(np.mean(np.sum((
        CAMERA.project(transform_points(s.T_camera_target, target.marker_corners.reshape(-1, 3))).reshape(-1, 4, 2)
        - CAMERA.project(transform_points(p.T_camera_target, target.marker_corners.reshape(-1, 3))).reshape(-1, 4, 2)
    ) ** 2, axis=2))) for s, p in zip(shots, placements, strict=True)]
    ours_mm, ours_deg = pose_error(result.T_parent_child, T_CAMERA_LIVOX_TRUE)
    fixed_mm, fixed_deg = pose_error(T_fixed, T_CAMERA_LIVOX_TRUE)
    return {"placements": len(pairs), "error": {"ours_mm": ours_mm, "ours_deg": ours_deg,
                                                "fixed_poses_mm": fixed_mm, "fixed_poses_deg": fixed_deg,
                                                "paper_mm": PAPER["v_target_mm"]},
            "sigma": result.std, "verdict": result.verdict.level,
            "image_rms_px": {"ours": result.residuals["image_rms_px"], "paper": PAPER["v_target_px"]},
            "target_pose_reprojection_px": {"median": float(np.median(corners_px)), "max": float(np.max(corners_px))},
            "solve_s": {"ours": ours_s, "fixed_poses": fixed_s}, "solve_ratio": ours_s / fixed_s}


def main() -> None:
    exterior_figures, test_field_figures = test_field()
    print(json.dumps({"test_field": test_field_figures, "exterior": exterior_figures, "v_target": v_target()},
                     indent=2))


if __name__ == "__main__":
    sys.exit(main())
