"""LiDAR-to-LiDAR extrinsic calibration: ``T_target_source`` with honest uncertainties.

Pipeline, as in the issue: an initial guess (given by the user, or
:func:`global_initial_guess` with Open3D FPFH features and RANSAC when there is
none), then GICP refinement with small_gicp (coarse stages with wide correspondence
distances for the basin, then a fine stage with a tight one for accuracy), then quality
numbers on the full-resolution clouds and a 1-sigma uncertainty of the transform. The answer is a
:class:`~backend.core.result.TransformResult` (``kind`` "lidar_lidar", ``method`` "gicp", ``parent`` "target",
``child`` "source"), as every transform solver's.

small_gicp's Hessian convention (read from ``small_gicp/factors/gicp_factor.hpp``
and ``registration/optimizer.hpp``, v1.0): the update is a *right* perturbation,
``T <- T @ se3_exp(delta)`` with ``delta = [omega (3, rad), v (3, m)]`` -- rotation
first, then translation, both expressed in the *source* (child) frame. Each
correspondence contributes ``J^T M J`` with ``J = [R @ skew(p_src), -R]`` (the
residual ``r = mu_target - T @ p_src``) and ``M = (C_target + R C_source R^T)^-1``;
``result.H`` is the sum at the last linearisation and ``result.error`` is
``0.5 * sum(r^T M r)`` there.

Noise model behind the Hessian sigma: the residuals are independent Gaussians
whose covariance is the GICP-fused covariance up to one unknown scale
``sigma^2``. small_gicp normalises its point covariances (plane-like, eigenvalues
1e-3, 1, 1), so the scale is estimated from the residual:
``sigma^2 = 2 * error / (inliers - 6)`` and ``cov(delta) = sigma^2 * H^-1``. That
is mapped to the reported parameters ``[t_x, t_y, t_z (m, parent/target axes),
r_x, r_y, r_z (rad, about the child/source axes)]``: ``dt = R @ v``, rotation
``omega`` as is. Neighbouring residuals are correlated (they share surfaces,
downsampling and scan-line patterns), which this model cannot see, so the reported
sigma is the larger of the Hessian sigma and the *spread*: the jackknife over scenes
when several are given (:func:`backend.calib.lidar_lidar.scenes.register_pairs`), and
otherwise the jackknife over azimuth sectors (re-registering without each sector of the
source), as the intrinsics solver does with views.

Every result carries a :class:`~backend.core.verdict.Verdict`: the sigmas against the stated
tolerances, the fit, and the independent cross-check across scenes. The sector jackknife is not
counted as a cross-check: it re-uses the same scan of the same place (its spread is already in the
sigma), so one scene is never more than ``check``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from backend.calib.lidar_lidar.checks import judge_fit, judge_one_scene
from backend.core.clouds import MIN_POINTS, check_cloud
from backend.core.result import (
    ProgressCallback,
    TransformResult,
    finite_or_none,
    jackknife_std,
    no_progress,
    transform_std,
    widen_covariance,
)
from backend.core.transforms import check_transform, params_between, transform_points
from backend.core.uncertainty import sigmas
from backend.core.verdict import Verdict

NO_OVERLAP_FITNESS = 0.005
"""Below this fitness the clouds are said not to overlap at all."""
ROTATION_EPSILON_RAD = np.radians(0.01)
TRANSLATION_EPSILON_M = 1e-4
"""Convergence of the fine stage: the last Gauss-Newton step was smaller than this (rad, m).
Tighter thresholds make real clouds oscillate between correspondence sets without gaining accuracy."""
CYCLE_TOLERANCE = (1e-3, np.radians(0.01))
"""A fine stage that ran out of iterations still counts as converged when one more Gauss-Newton
step moves less than this (m, rad): it is alternating between two correspondence sets
(seen on the real OpenCalib pair: a 0.5 mm / 0.004 deg two-cycle), not diverging."""
GLOBAL_VOXEL_FACTORS = (0.6, 1.0, 1.6)
GLOBAL_SEEDS = 3
"""Global registration tries these multiples of ``global_voxel_m``, each with this many RANSAC seeds."""
SECTORS = 8
"""Azimuth sectors of the source cloud for the single-scene jackknife."""


@dataclass
class LidarLidarSettings:
    """How to register. Lengths in metres."""

    voxel_m: float = 0.1
    """Downsampling resolution of the fine GICP stage (m)."""
    max_correspondence_m: float = 0.2
    """Largest source-target distance that counts as a correspondence in the fine stage, and the
    inlier distance for fitness, RMSE and cloud-to-cloud statistics (m). Keep it tight: points
    without a true counterpart (parts only one LiDAR sees) that still find a partner within this
    distance bias the result (in simulation: 0 mm at 0.2 m, 5 mm at 0.5 m, 11 mm at 1 m)."""
    num_neighbors: int = 20
    """Neighbours used to estimate each point's covariance for GICP."""
    max_iterations: int = 50
    """Gauss-Newton iterations per GICP stage."""
    num_threads: int = 2
    coarse_to_fine: bool = True
    """Run coarse stages before the fine one, to widen the basin of convergence."""
    coarse_voxel_m: float = 0.3
    """Downsampling resolution of the coarse stages (m)."""
    coarse_max_correspondence_m: tuple[float, ...] = (1.5, 0.5)
    """Correspondence distances of the successive coarse stages (m)."""
    min_fitness: float = 0.05
    """A result with a smaller fitness (fraction of source points with a target point within
    ``max_correspondence_m``) is a poor fit: ``converged=False`` and a warning."""
    spread: bool = True
    """Also estimate sigmas from the spread (jackknife over frame pairs, or over azimuth sectors
    of a single pair) and report the larger sigma per axis."""
    global_voxel_m: float = 0.5
    """Voxel size of the FPFH + RANSAC global registration when no initial guess is given (m)."""


@dataclass
class SceneResult:
    """One scene's own solve (its frame pairs only), kept beside the joint solve over every scene."""

    pairs: list[int]
    """Indices (from 0) of the frame pairs taken in this place."""
    T_target_source: np.ndarray
    """4x4 from this scene alone (m)."""
    fitness: float
    rmse_m: float
    converged: bool
    covariance: np.ndarray
    """6x6 of this scene's solve (:data:`~backend.core.result.TRANSFORM_PARAMETERS`)."""
    deviation: np.ndarray | None = None
    """(6,) this scene's solve about the joint solve of the *other* scenes (m, rad); None with one scene."""
    allowance: np.ndarray | None = None
    """(6,) the largest deviation the cross-check lets pass, per axis (m, rad); None with one scene."""

    @property
    def agrees(self) -> bool | None:
        """Whether this scene agrees with the others (None: nothing to compare with)."""
        if self.deviation is None or self.allowance is None:
            return None
        return bool(self.converged and np.all(np.abs(self.deviation) <= self.allowance))

    def to_record(self) -> dict[str, Any]:
        deviation = None if self.deviation is None else {
            "trans_m": finite_or_none(self.deviation[:3]), "rot_deg": finite_or_none(np.degrees(self.deviation[3:]))}
        return {
            "pairs": list(self.pairs),
            "T_target_source": self.T_target_source.tolist(),
            "fitness": self.fitness,
            "rmse_m": self.rmse_m,
            "converged": self.converged,
            "std": transform_std(self.covariance),
            "deviation": deviation,
            "agrees": self.agrees,
        }


def scene_spread(scenes: list[SceneResult]) -> dict[str, float] | None:
    """The largest distance between two scenes' own solves: ``trans_m`` (m) and ``rot_deg`` (deg), or None with
    fewer than two scenes."""
    solved = [s.T_target_source for s in scenes]
    if len(solved) < 2:
        return None
    steps = np.array([params_between(a, b) for i, a in enumerate(solved) for b in solved[i + 1:]])
    return {"trans_m": float(np.linalg.norm(steps[:, :3], axis=1).max()),
            "rot_deg": float(np.degrees(np.linalg.norm(steps[:, 3:], axis=1).max()))}


# ---------------------------------------------------------------- input checks


def evaluate_alignment(source_points: np.ndarray, target_points: np.ndarray, T_target_source: np.ndarray,
                       max_distance_m: float, target_tree: cKDTree | None = None,
                       num_threads: int = 2) -> dict[str, Any]:
    """Fitness, inlier RMSE and cloud-to-cloud statistics of an alignment, as Open3D's
    ``evaluate_registration``: a source point is an inlier when its nearest target point is
    within ``max_distance_m`` (m) once mapped by ``T_target_source``.

    Returns ``{"fitness", "rmse_m", "c2c_m": {"mean", "median", "p95", "std"}, "distances_m"}``
    with the inlier distances (m); statistics are 0 when there are no inliers.
    """
    tree = target_tree if target_tree is not None else cKDTree(target_points)
    aligned = transform_points(T_target_source, source_points)
    d, _ = tree.query(aligned, k=1, distance_upper_bound=max_distance_m, workers=num_threads)
    inlier = np.isfinite(d)
    return {"fitness": float(inlier.mean()), **distance_statistics(d[inlier])}


def distance_statistics(d: np.ndarray) -> dict[str, Any]:
    """``{"rmse_m", "c2c_m": {"mean", "median", "p95", "std"}, "distances_m"}`` of inlier distances ``d`` (m);
    zeros when there are none."""
    if d.size == 0:
        return {"rmse_m": 0.0, "c2c_m": {"mean": 0.0, "median": 0.0, "p95": 0.0, "std": 0.0}, "distances_m": d}
    c2c = {"mean": float(d.mean()), "median": float(np.median(d)), "p95": float(np.percentile(d, 95)),
           "std": float(d.std())}
    return {"rmse_m": float(np.sqrt(np.mean(d**2))), "c2c_m": c2c, "distances_m": d}


# ---------------------------------------------------------------- global registration


def global_initial_guess(source_points: np.ndarray, target_points: np.ndarray, voxel_m: float = 0.5,
                         seed: int = 0) -> tuple[np.ndarray, float]:
    """``T_target_source`` from FPFH features and RANSAC (Open3D) when no guess exists.

    Downsamples both clouds at ``voxel_m`` (m), estimates normals (radius 2 voxels) and FPFH
    (radius 5 voxels), and runs ``registration_ransac_based_on_feature_matching`` with a
    1.5-voxel inlier distance. Returns the transform and RANSAC's fitness. Only a starting
    point for GICP: its accuracy is about a voxel.
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)

    def features(points: np.ndarray):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel_m)
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel_m, max_nn=30))
        fpfh = reg.compute_fpfh_feature(cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel_m, max_nn=100))
        return cloud, fpfh

    source, source_fpfh = features(source_points)
    target, target_fpfh = features(target_points)
    distance = 1.5 * voxel_m
    result = reg.registration_ransac_based_on_feature_matching(
        source, target, source_fpfh, target_fpfh, True, distance,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(distance)],
        reg.RANSACConvergenceCriteria(200000, 0.999))
    return np.asarray(result.transformation).copy(), float(result.fitness)


# ---------------------------------------------------------------- GICP


def _gicp(source, target, target_tree, T_init: np.ndarray, settings: LidarLidarSettings, max_distance_m: float,
          fine: bool, max_iterations: int | None = None):
    """One small_gicp GICP run between preprocessed clouds (see :func:`preprocess`)."""
    import small_gicp

    kwargs = {"rotation_epsilon": ROTATION_EPSILON_RAD, "translation_epsilon": TRANSLATION_EPSILON_M} if fine else {}
    return small_gicp.align(target, source, target_tree, init_T_target_source=T_init, registration_type="GICP",
                            max_correspondence_distance=max_distance_m, num_threads=settings.num_threads,
                            max_iterations=max_iterations or settings.max_iterations, **kwargs)


def preprocess(points: np.ndarray, voxel_m: float, settings: LidarLidarSettings):
    """Voxel-downsampled small_gicp cloud with covariances, and its KD-tree."""
    import small_gicp

    return small_gicp.preprocess_points(points, downsampling_resolution=voxel_m,
                                        num_neighbors=settings.num_neighbors, num_threads=settings.num_threads)


def _coarse_stages(coarse_source, coarse_target, coarse_tree, T: np.ndarray, settings: LidarLidarSettings,
                   progress: ProgressCallback = no_progress) -> np.ndarray:
    """The coarse GICP stages (``coarse_max_correspondence_m``, widest first) from ``T``."""
    for distance in settings.coarse_max_correspondence_m:
        progress(0.25, f"coarse GICP ({settings.coarse_voxel_m} m voxels, {distance} m correspondences)")
        T = np.asarray(_gicp(coarse_source, coarse_target, coarse_tree, T, settings, distance,
                             fine=False).T_target_source)
    return T


def _delta_to_params(T: np.ndarray) -> np.ndarray:
    """Jacobian (6x6) from small_gicp's ``delta = [omega, v]`` (source frame) to our
    ``[t (target axes), r (source axes)]``: ``dt = R v``, ``dr = omega``."""
    A = np.zeros((6, 6))
    A[:3, 3:] = T[:3, :3]
    A[3:, :3] = np.eye(3)
    return A


def hessian_covariance(result, T: np.ndarray) -> np.ndarray:
    """``sigma^2 H^-1`` in our parameters (see the module docstring); NaN if undetermined."""
    H = np.asarray(result.H, dtype=float)
    dof = int(result.num_inliers) - 6
    if dof <= 0 or not np.isfinite(H).all():
        return np.full((6, 6), np.nan)
    sigma2 = 2.0 * float(result.error) / dof
    # Scale to unit diagonal before inverting: rotation and translation blocks differ in scale.
    d = np.sqrt(np.clip(np.diag(H), 1e-300, None))
    Hs = H / np.outer(d, d)
    if np.linalg.cond(Hs) > 1e12:
        return np.full((6, 6), np.nan)
    cov_delta = sigma2 * np.linalg.inv(Hs) / np.outer(d, d)
    A = _delta_to_params(T)
    cov = A @ cov_delta @ A.T
    return 0.5 * (cov + cov.T)


def sector_jackknife(sources: list[np.ndarray], solve: Callable[[list[Any]], np.ndarray], T: np.ndarray,
                     settings: LidarLidarSettings, progress: ProgressCallback) -> np.ndarray | None:
    """Leave-one-azimuth-sector-out jackknife std (6,) about ``T`` (m, rad), or None.

    Every source cloud (sensor frame, m) is split into ``SECTORS`` wedges by azimuth around the
    source origin; each wedge is left out of all of them in turn, the rest preprocessed at the fine
    voxel size and ``solve(kept_clouds)`` re-run (it returns ``T_target_source``).
    ``var = (n-1)/n * sum((p_i - mean)^2)``. Whole structures (a wall, a row of poles) are the
    correlated units here, as views are for the intrinsics solver.
    """
    sectors = []
    for points in sources:
        azimuth = np.arctan2(points[:, 1], points[:, 0])
        sectors.append(np.minimum(((azimuth + np.pi) / (2 * np.pi) * SECTORS).astype(int), SECTORS - 1))
    estimates = []
    for i in range(SECTORS):
        progress(0.7 + 0.25 * i / SECTORS, f"spread: re-registering without azimuth sector {i + 1} of {SECTORS}")
        kept = [points[sector != i] for points, sector in zip(sources, sectors, strict=True)]
        if any(len(k) < MIN_POINTS for k in kept) or all(len(k) == len(p) for k, p in zip(kept, sources, strict=True)):
            continue
        estimates.append(params_between(T, solve([preprocess(k, settings.voxel_m, settings)[0] for k in kept])))
    if len(estimates) < 3:
        return None
    return jackknife_std(np.array(estimates))


def _refine(source: np.ndarray, target: np.ndarray, T_init: np.ndarray, settings: LidarLidarSettings,
            progress: ProgressCallback):
    """Coarse-to-fine GICP; returns (fine small_gicp result, T, converged, a note or None, fine target, its tree)."""
    T = T_init
    if settings.coarse_to_fine:
        coarse_source, _ = preprocess(source, settings.coarse_voxel_m, settings)
        coarse_target, coarse_tree = preprocess(target, settings.coarse_voxel_m, settings)
        T = _coarse_stages(coarse_source, coarse_target, coarse_tree, T, settings, progress)
    progress(0.45, f"fine GICP ({settings.voxel_m} m voxels, {settings.max_correspondence_m} m correspondences)")
    fine_source, _ = preprocess(source, settings.voxel_m, settings)
    fine_target, fine_tree = preprocess(target, settings.voxel_m, settings)
    result = _gicp(fine_source, fine_target, fine_tree, T, settings, settings.max_correspondence_m, fine=True)
    T = np.asarray(result.T_target_source).copy()
    converged, note = bool(result.converged), None
    if not converged:
        step = _gicp(fine_source, fine_target, fine_tree, T, settings, settings.max_correspondence_m, fine=True,
                     max_iterations=1)
        motion = params_between(T, np.asarray(step.T_target_source))
        dt, dr = float(np.linalg.norm(motion[:3])), float(np.linalg.norm(motion[3:]))
        if dt < CYCLE_TOLERANCE[0] and dr < CYCLE_TOLERANCE[1]:
            converged = True
            note = (f"fine GICP alternates between correspondence sets (last step {dt * 1000:.2f} mm, "
                    f"{np.degrees(dr):.4f} deg); taken as converged")
    return result, T, converged, note, fine_target, fine_tree


def best_global_guess(source: np.ndarray, target: np.ndarray, settings: LidarLidarSettings,
                       progress: ProgressCallback) -> np.ndarray:
    """The best of several FPFH + RANSAC guesses, judged after a coarse GICP from each.

    One RANSAC run is fast but unreliable on sparse scans (in simulation it lands 0.3-3 m off
    about half the time), so it is run at ``GLOBAL_VOXEL_FACTORS`` x ``settings.global_voxel_m``
    with ``GLOBAL_SEEDS`` seeds each; every candidate gets the coarse GICP stages and the one
    with the highest fitness at ``coarse_max_correspondence_m[-1]`` wins.
    """
    coarse_source, _ = preprocess(source, settings.coarse_voxel_m, settings)
    coarse_target, coarse_tree = preprocess(target, settings.coarse_voxel_m, settings)
    tree = cKDTree(target)
    best, best_fitness = np.eye(4), -1.0
    candidates = [(f * settings.global_voxel_m, seed) for f in GLOBAL_VOXEL_FACTORS for seed in range(GLOBAL_SEEDS)]
    for i, (voxel, seed) in enumerate(candidates):
        progress(0.2 * i / len(candidates), f"no initial guess: global registration (FPFH + RANSAC, "
                                            f"{voxel:.2f} m voxels, seed {seed})")
        T, _ = global_initial_guess(source, target, voxel, seed)
        T = _coarse_stages(coarse_source, coarse_target, coarse_tree, T, settings)
        fitness = evaluate_alignment(source, target, T, settings.coarse_max_correspondence_m[-1], tree,
                                     settings.num_threads)["fitness"]
        if fitness > best_fitness:
            best, best_fitness = T.copy(), fitness
    return best


def fit_warnings(fitness: float, converged: bool, settings: LidarLidarSettings) -> list[str]:
    """Why a refinement must not be accepted (empty when it may be)."""
    warnings = []
    if not converged:
        warnings.append(f"GICP did not converge within {settings.max_iterations} iterations; not accepted - "
                        "give a better initial guess")
    if fitness < NO_OVERLAP_FITNESS:
        warnings.append(f"the clouds do not overlap after alignment (fitness {fitness:.3f}); not accepted - "
                        "check the initial guess and that both LiDARs see the same scene")
    elif fitness < settings.min_fitness:
        warnings.append(f"poor fit: fitness {fitness:.3f} < {settings.min_fitness} at "
                        f"{settings.max_correspondence_m} m; not accepted")
    return warnings





def initial_guess(T_init: np.ndarray | None, source: np.ndarray, target: np.ndarray, settings: LidarLidarSettings,
                  progress: ProgressCallback, warnings: list[str]) -> tuple[np.ndarray, str]:
    """The checked initial ``T_target_source`` and how it was found ("given", or "global": FPFH + RANSAC from
    ``source`` into ``target`` when ``T_init`` is None); what the user should know is appended to ``warnings``."""
    if T_init is None:
        warnings.append("no initial guess: started from global registration (FPFH + RANSAC); "
                        "check the alignment by eye, symmetric scenes can fool it")
        return best_global_guess(source, target, settings, progress), "global"
    T_init, deviation = check_transform(T_init, "T_init")
    if deviation > 1e-4:
        warnings.append(f"T_init: the 3x3 was not orthonormal (max |R^T R - I| = {deviation:.3g}); "
                        "projected onto the nearest rotation")
    return T_init, "given"


def assemble_result(T: np.ndarray, quality: dict[str, Any], covariance: np.ndarray, cov_h: np.ndarray,
                    std_spread: np.ndarray | None, spread_source: str, settings: LidarLidarSettings, ok: bool,
                    started: float, init: tuple[np.ndarray, str], fit: Any, verdict: Verdict,
                    scenes: list[SceneResult], warnings: list[str]) -> TransformResult:
    """The :class:`TransformResult` of a solve from its parts (``parent`` "target", ``child`` "source": the
    caller names them by sensor with :meth:`TransformResult.named`).

    ``quality`` is :func:`evaluate_alignment`'s (it becomes the residuals ``fitness``, ``rmse_m`` and ``c2c_m``),
    ``started`` the ``time.perf_counter()`` at the start (s), ``init`` the initial guess and its method, ``fit``
    the fine stage (its ``iterations`` and ``num_inliers``); ``spread_source`` names what ``std_spread`` (if any,
    m and rad) was taken over. The diagnostics hold every scene's own solve (:meth:`SceneResult.to_record`), the
    ``scene_spread``, both sigma estimates ``std_hessian`` / ``std_spread`` (6, m and rad, None where
    undetermined), ``T_init``, ``init_method`` ("given" or "global"), ``iterations`` and ``num_inliers``.
    """
    return TransformResult(
        kind="lidar_lidar", method="gicp", parent="target", child="source", T_parent_child=T, covariance=covariance,
        residuals={"fitness": quality["fitness"], "rmse_m": quality["rmse_m"], "c2c_m": dict(quality["c2c_m"])},
        diagnostics={
            "scenes": [scene.to_record() for scene in scenes],
            "scene_spread": scene_spread(scenes),
            "std_hessian": finite_or_none(sigmas(cov_h)),
            "std_spread": finite_or_none(std_spread),
            "spread_source": spread_source if std_spread is not None else None,
            "T_init": np.asarray(init[0], dtype=float).tolist(),
            "init_method": init[1],
            "iterations": int(fit.iterations),
            "num_inliers": int(fit.num_inliers),
        },
        settings=asdict(settings), converged=ok, verdict=verdict, warnings=warnings,
        seconds=time.perf_counter() - started)


def register_pair(source_points: np.ndarray, target_points: np.ndarray, T_init: np.ndarray | None = None,
                  settings: LidarLidarSettings | None = None, progress: ProgressCallback = no_progress,
                  source_name: str = "source", target_name: str = "target") -> TransformResult:
    """Estimate ``T_target_source`` (maps source points into the target frame) from one frame pair: a
    :class:`TransformResult` with ``parent`` "target" and ``child`` "source" (see :func:`assemble_result`).

    ``source_points`` / ``target_points`` are (N, 3) arrays in metres (non-finite rows are dropped
    with a warning). ``T_init`` is the initial ``T_target_source``; without one, FPFH + RANSAC
    (:func:`global_initial_guess`) provides it. Raises :class:`InputError` naming
    ``source_name`` / ``target_name`` for empty, all-non-finite, too small or millimetre-looking
    clouds and for a non-rigid ``T_init``. A refinement that did not converge or fits poorly is
    returned with ``converged=False``, a warning and a ``reject`` verdict: the caller must not accept it.
    """
    settings = settings or LidarLidarSettings()
    started = time.perf_counter()
    source, dropped_s = check_cloud(source_points, source_name)
    target, dropped_t = check_cloud(target_points, target_name)
    warnings = [f"{name}: dropped {n} non-finite points" for name, n in ((source_name, dropped_s),
                                                                          (target_name, dropped_t)) if n]
    T_init, init_method = initial_guess(T_init, source, target, settings, progress, warnings)

    result, T, converged, note, fine_target, fine_tree = _refine(source, target, T_init, settings, progress)
    progress(0.65, "evaluating the alignment")
    quality = evaluate_alignment(source, target, T, settings.max_correspondence_m, num_threads=settings.num_threads)
    warnings += [note] if note else []
    quality_warnings = fit_warnings(quality["fitness"], converged, settings)
    warnings += quality_warnings
    ok = not quality_warnings
    cov_h = hessian_covariance(result, T)
    std_spread = None
    if settings.spread and ok:
        std_spread = sector_jackknife([source], lambda kept: np.asarray(_gicp(
            kept[0], fine_target, fine_tree, T, settings, settings.max_correspondence_m, fine=True).T_target_source),
            T, settings, progress)
    covariance = widen_covariance(cov_h, std_spread)
    judge = judge_fit(transform_std(covariance), quality["fitness"], ok, quality_warnings, settings)
    judge_one_scene(judge, SECTORS if std_spread is not None else None)
    progress(1.0, "done")
    return assemble_result(T, quality, covariance, cov_h, std_spread, "sectors", settings, ok, started,
                           (T_init, init_method), result, judge.verdict(),
                           [SceneResult([0], T, quality["fitness"], quality["rmse_m"], ok, covariance)], warnings)
