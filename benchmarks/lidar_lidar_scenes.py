#!/usr/bin/env python
"""LiDAR-to-LiDAR over several scenes: our joint solve against per-scene Open3D GICP solves averaged.

What it measures, in one run on the same data:

- ``joint_s`` / ``joint_error_*``: ``register_pairs`` over every scene with
  ``LidarLidarSettings(spread=False)``: the joint coarse-to-fine GICP objective over all scenes, plus each
  scene's own solve and the leave-one-scene-out solves of the cross-check (the verdict), from an initial
  guess 19.7 cm / 5 deg off the truth;
- ``joint_with_sigma_s``: the same with the default settings (each scene's sigma also gets its
  azimuth-sector jackknife), and its verdict level;
- ``baseline_s`` / ``baseline_error_*``: the in-run baseline, Open3D's GICP
  (``registration_generalized_icp``) on each scene from the same guess, coarse-to-fine as ours (0.3 m
  voxels at 1.5 m then 0.5 m correspondences, then 0.1 m voxels at 0.2 m; 50 iterations a stage), the
  per-scene transforms averaged (translations by their mean, rotations by ``Rotation.mean``). Its time
  includes building and downsampling the Open3D clouds (GICP estimates its own covariances);
- ``ours_scene_error_mm``: the mean error of our per-scene solves (what one scene alone gives);
- ``*_error_mm`` / ``*_error_deg``: norm of the translation error (mm) and angle of the rotation error
  (deg) against the simulation's truth;
- ``real_pair``: the real OpenCalib pair (one scene, ``../shared/data/opencalib_lidar2lidar_pair``) from
  its reference (projected onto a rotation) moved 5 cm / 2 deg: ours (``register_pair``; ``ours_s`` with
  ``spread=False``, ``ours_with_sigma_s`` and the sigma and verdict with the default settings, which add the
  8-sector jackknife) and Open3D GICP (0.1 m voxels, 0.5 m correspondences, 100 iterations, as in
  tests/calib/lidar_lidar/test_gicp.py): time, fitness at 0.2 m, offset from the reference (which is not a surveyed
  truth: see tests/calib/lidar_lidar/test_gicp.py), and our verdict.

Clouds: the simulated yard (``LidarScene``, with the board) scanned from ``PLACEMENTS`` (the robot in
four places) by the two LiDARs of ``benchmarks/lidar_lidar.py``, each a 32-beam spinning LiDAR
(-25..15 deg, 0.2 deg columns, 1 cm range noise); the source's rear quarter is blocked (as by the
vehicle). Times are the median of ``REPEATS`` runs (time.perf_counter). Ratios are ours / baseline:
> 1 means ours is slower (time) or further from the truth (error).

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/lidar_lidar_scenes.py
"""

import json
import os
import time
from pathlib import Path

import numpy as np
from bench_util import REPEATS, log, median_time, peak_rss_mb, pose_error
from scipy.spatial.transform import Rotation

from backend.calib.lidar_lidar.gicp import LidarLidarSettings, evaluate_alignment, register_pair
from backend.calib.lidar_lidar.scenes import register_pairs
from backend.core.transforms import check_transform, from_xyz_ypr, invert, make_T, transform_error
from backend.devices.cloud_files import read_cloud
from backend.sim.lidar_scene import LidarScene

T_BASE_SOURCE = from_xyz_ypr(np.array([0.4, 0.2, 1.1]), np.radians([0.0, 2.0, 0.0]))
T_BASE_TARGET = from_xyz_ypr(np.array([-0.3, -0.35, 0.9]), np.radians([100.0, 12.0, -5.0]))
"""The two LiDARs on the robot (as in benchmarks/lidar_lidar.py)."""
PLACEMENTS = [from_xyz_ypr(np.array(xyz), np.radians([yaw, 0.0, 0.0])) for xyz, yaw in
              [([0.0, 0.0, 0.0], 0.0), ([1.0, 0.5, 0.0], 30.0), ([-0.5, -1.0, 0.0], -50.0), ([2.0, -1.5, 0.0], 120.0)]]
"""The robot in four places of the yard (T_world_base)."""
SCAN = {"beams": 32, "vertical_fov_deg": (-25.0, 15.0), "azimuth_step_deg": 0.2, "range_noise_m": 0.01}
INIT_OFFSET_M = np.array([0.12, -0.14, 0.07])
INIT_OFFSET_DEG = 5.0
INIT_AXIS = np.array([0.3, -0.5, 0.8])
"""The initial guess is the truth composed with this offset: 19.7 cm, 5 deg about INIT_AXIS."""
BASELINE_STAGES = [(0.3, 1.5), (0.3, 0.5), (0.1, 0.2)]
"""Open3D GICP stages: (voxel m, correspondence distance m), as our coarse-to-fine defaults."""
REAL_PAIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "opencalib_lidar2lidar_pair"


def open3d_gicp(source, target, T_init, stages, iterations=50):
    """Open3D generalized ICP from ``T_init`` through ``stages`` of (voxel m, correspondence m): T_target_source."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    T = T_init
    for voxel, distance in stages:
        clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(voxel)
                  for p in (source, target)]
        T = np.asarray(reg.registration_generalized_icp(
            clouds[0], clouds[1], distance, T, reg.TransformationEstimationForGeneralizedICP(),
            reg.ICPConvergenceCriteria(max_iteration=iterations)).transformation)
    return T


def averaged(transforms):
    """The mean of several transforms: translations averaged, rotations by ``Rotation.mean``."""
    rotation = Rotation.from_matrix(np.array([T[:3, :3] for T in transforms])).mean().as_matrix()
    return make_T(rotation, np.mean([T[:3, 3] for T in transforms], axis=0))


def scan_scenes():
    """(source, target) points (m, sensor frames) of every placement; the source's rear quarter blocked."""
    scene = LidarScene()
    pairs = []
    for i, T_world_base in enumerate(PLACEMENTS):
        source = scene.scan_3d(T_world_base @ T_BASE_SOURCE, **SCAN, rng=2 * i + 1)
        target = scene.scan_3d(T_world_base @ T_BASE_TARGET, **SCAN, rng=2 * i + 2)
        front = np.abs(np.angle(np.exp(1j * (source.azimuth_rad - np.pi)))) > np.radians(45)
        pairs.append((source.points[front], target.points))
    return pairs


def real_pair():
    """Ours and Open3D GICP on the real OpenCalib pair from its reference moved by 5 cm / 2 deg."""
    source = read_cloud(REAL_PAIR / "p64.pcd").points
    target = read_cloud(REAL_PAIR / "qt.pcd").points
    data = json.loads((REAL_PAIR / "p64-to-qt-extrinsic.json").read_text())
    T_ref, _ = check_transform(np.array(next(iter(data.values()))["param"]["sensor_calib"]["data"]), "reference")
    rng = np.random.default_rng(0)
    t, axis = rng.normal(size=3), rng.normal(size=3)
    T_init = T_ref @ make_T(Rotation.from_rotvec(np.radians(2.0) * axis / np.linalg.norm(axis)).as_matrix(),
                            0.05 * t / np.linalg.norm(t))
    log("real pair: ours (spread=False, then the default settings for the sigma and verdict) ...")
    started = time.perf_counter()
    register_pair(source, target, T_init, LidarLidarSettings(spread=False))
    ours_s = time.perf_counter() - started
    started = time.perf_counter()
    ours = register_pair(source, target, T_init)
    ours_with_sigma_s = time.perf_counter() - started
    log("real pair: Open3D GICP ...")
    started = time.perf_counter()
    baseline = open3d_gicp(source, target, T_init, [(0.1, 0.5)], iterations=100)
    baseline_s = time.perf_counter() - started

    def fitness(T):
        return round(evaluate_alignment(source, target, T, 0.2)["fitness"], 4)

    ours_mm, ours_deg = pose_error(ours.T_parent_child, T_ref)
    base_mm, base_deg = pose_error(baseline, T_ref)
    apart_mm, apart_deg = pose_error(ours.T_parent_child, baseline)
    return {
        "ours_s": round(ours_s, 3), "ours_with_sigma_s": round(ours_with_sigma_s, 3),
        "baseline_s": round(baseline_s, 3), "time_ratio": round(ours_s / baseline_s, 2),
        "fitness": fitness(ours.T_parent_child), "baseline_fitness": fitness(baseline),
        "reference_fitness": fitness(T_ref),
        "from_reference_mm": round(ours_mm, 1), "from_reference_deg": round(ours_deg, 3),
        "baseline_from_reference_mm": round(base_mm, 1), "baseline_from_reference_deg": round(base_deg, 3),
        "ours_to_baseline_mm": round(apart_mm, 1), "ours_to_baseline_deg": round(apart_deg, 3),
        "std_trans_mm": [round(1000 * s, 1) for s in ours.std_vector[:3]],
        "std_rot_deg": [round(float(np.degrees(s)), 3) for s in ours.std_vector[3:]],
        "verdict": ours.verdict.level,
    }


def main():
    started = time.perf_counter()
    log(f"load average at start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")

    log(f"scanning the simulated yard from {len(PLACEMENTS)} placements ...")
    pairs = scan_scenes()
    T_true = invert(T_BASE_TARGET) @ T_BASE_SOURCE
    axis = INIT_AXIS / np.linalg.norm(INIT_AXIS)
    T_init = T_true @ make_T(Rotation.from_rotvec(np.radians(INIT_OFFSET_DEG) * axis).as_matrix(), INIT_OFFSET_M)
    log(f"  points per scene (source, target): {[(len(s), len(t)) for s, t in pairs]}")

    no_spread = LidarLidarSettings(spread=False)
    log(f"timing the joint solve (spread=False) x{REPEATS} ...")
    joint_s = median_time(lambda: register_pairs(pairs, T_init, no_spread))
    log(f"timing per-scene Open3D GICP, averaged x{REPEATS} ...")
    baseline_s = median_time(lambda: [open3d_gicp(s, t, T_init, BASELINE_STAGES) for s, t in pairs])
    log("the joint solve with the default settings (sector-widened scene sigmas) ...")
    started_sigma = time.perf_counter()
    with_sigma = register_pairs(pairs, T_init)
    joint_with_sigma_s = time.perf_counter() - started_sigma

    joint = register_pairs(pairs, T_init, no_spread)
    per_scene = [open3d_gicp(s, t, T_init, BASELINE_STAGES) for s, t in pairs]
    joint_mm, joint_deg = pose_error(joint.T_parent_child, T_true)
    base_mm, base_deg = pose_error(averaged(per_scene), T_true)
    scene_errors = [pose_error(np.array(s["T_target_source"]), T_true) for s in joint.diagnostics["scenes"]]
    base_scene_errors = [pose_error(T, T_true) for T in per_scene]
    err_t, err_r = transform_error(with_sigma.T_parent_child, T_true)
    normalised = np.abs(np.r_[err_t, np.radians(err_r)]) / with_sigma.std_vector
    log(f"  joint: {joint_mm:.3f} mm {joint_deg:.4f} deg; its scenes alone: "
        f"{[f'{e[0]:.2f} mm' for e in scene_errors]}; verdict {with_sigma.verdict.level}")
    log(f"  Open3D per scene: {[f'{e[0]:.2f} mm' for e in base_scene_errors]}; averaged {base_mm:.3f} mm "
        f"{base_deg:.4f} deg")

    real = real_pair()
    log(f"  real pair: {real}")
    log(f"done in {time.perf_counter() - started:.1f} s; load average at end: {os.getloadavg()[0]:.2f}")
    print(json.dumps({
        "benchmark": "lidar_lidar_scenes",
        "scenes": len(pairs),
        "points": [[len(s), len(t)] for s, t in pairs],
        "joint_s": round(joint_s, 3),
        "joint_with_sigma_s": round(joint_with_sigma_s, 3),
        "baseline_s": round(baseline_s, 3),
        "time_ratio": round(joint_s / baseline_s, 2),
        "joint_error_mm": round(joint_mm, 3),
        "joint_error_deg": round(joint_deg, 4),
        "baseline_error_mm": round(base_mm, 3),
        "baseline_error_deg": round(base_deg, 4),
        "error_ratio_mm": round(joint_mm / base_mm, 3),
        "error_ratio_deg": round(joint_deg / base_deg, 3),
        "ours_scene_error_mm": round(float(np.mean([e[0] for e in scene_errors])), 3),
        "baseline_scene_error_mm": round(float(np.mean([e[0] for e in base_scene_errors])), 3),
        "error_over_sigma_max": round(float(normalised.max()), 2),
        "verdict": with_sigma.verdict.level,
        "scene_spread": {k: round(v, 4) for k, v in with_sigma.diagnostics["scene_spread"].items()},
        "real_pair": real,
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "cpu_count": os.cpu_count(),
    }))


if __name__ == "__main__":
    main()
