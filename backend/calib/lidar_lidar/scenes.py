"""LiDAR-to-LiDAR over several scenes: one ``T_target_source`` for every frame pair, cross-checked across scenes.

A rig captured in several places (scenes) gives one frame pair per place (or several). All pairs
share one unknown, so they are solved as *one* GICP objective: the sum over every pair of
small_gicp's GICP cost, minimised by Gauss-Newton in small_gicp's right perturbation (see
:mod:`backend.calib.lidar_lidar.gicp`), coarse stages first, then the fine one. small_gicp linearises
one pair at a time (``align`` with one iteration returns that pair's ``H`` and ``b`` at the given
transform); no library sums several pairs' normal equations, so the step is taken here.

Scenes are the independent units. Pairs whose target clouds lie on each other where they were
taken (:func:`~backend.core.clouds.group_by_place`) were taken in one place and form one scene: repeated frames of a
rig standing still are not independent evidence. Each scene is also solved on its own, and the
cross-check of the verdict compares it with the joint solve of the *other* scenes: a scene agrees
when, on every axis, it lies within the larger of the stated tolerance and
:data:`CROSS_CHECK_SIGMAS` times the combined 1-sigma of the two (so a scene that leaves one axis
loose, a corridor, still agrees along it). A cloud that moved, or a LiDAR knocked between scenes,
makes its scene disagree. The reported sigma is the larger of the joint Hessian sigma and the
leave-one-scene-out jackknife; with one scene, the azimuth-sector jackknife, and the cross-check is
named missing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser.transforms as vtf

from backend.calib.lidar_lidar.checks import judge_fit, judge_one_scene, scenes_cross_check
from backend.calib.lidar_lidar.gicp import (
    CYCLE_TOLERANCE,
    ROTATION_EPSILON_RAD,
    SECTORS,
    TRANSLATION_EPSILON_M,
    LidarLidarSettings,
    SceneResult,
    assemble_result,
    distance_statistics,
    evaluate_alignment,
    fit_warnings,
    hessian_covariance,
    initial_guess,
    preprocess,
    register_pair,
    sector_jackknife,
)
from backend.core.clouds import check_cloud, group_by_place
from backend.core.errors import InputError
from backend.core.result import (
    ProgressCallback,
    TransformResult,
    jackknife_std,
    no_progress,
    transform_std,
    widen_covariance,
)
from backend.core.transforms import params_between
from backend.core.verdict import CROSS_CHECK_SIGMAS, ROTATION_TOLERANCE_DEG, TRANSLATION_TOLERANCE_M

TOLERANCE = np.r_[np.full(3, TRANSLATION_TOLERANCE_M), np.full(3, np.radians(ROTATION_TOLERANCE_DEG))]
"""The stated tolerance per axis (m, rad): deviations within it always agree."""
COARSE_EPSILON = (np.radians(0.1), 1e-3)
"""Convergence of a coarse stage (rad, m): small_gicp's defaults."""


@dataclass
class _Pair:
    """One frame pair, checked (m, sensor frames) and preprocessed for the coarse and fine stages."""

    source: np.ndarray
    target: np.ndarray
    coarse: tuple[Any, Any, Any]
    """(source, target, target tree) at the coarse voxel size."""
    fine: tuple[Any, Any, Any]
    """(source, target, target tree) at the fine voxel size."""


@dataclass
class JointFit:
    """A Gauss-Newton solve of the summed GICP cost of several pairs (names as small_gicp's result)."""

    T_target_source: np.ndarray
    H: np.ndarray
    """6x6 sum of the pairs' GICP Hessians at the last linearisation (small_gicp's ``[omega, v]``)."""
    error: float
    """Sum of the pairs' GICP errors (``0.5 sum r^T M r``) at the last linearisation."""
    num_inliers: int
    iterations: int
    converged: bool
    note: str | None = None


def _prepare(source: np.ndarray, target: np.ndarray, settings: LidarLidarSettings) -> _Pair:
    def stage(voxel_m: float) -> tuple[Any, Any, Any]:
        return (preprocess(source, voxel_m, settings)[0], *preprocess(target, voxel_m, settings))

    return _Pair(source, target, stage(settings.coarse_voxel_m), stage(settings.voxel_m))


def joint_gicp(clouds: list[tuple[Any, Any, Any]], T: np.ndarray, settings: LidarLidarSettings, distance_m: float,
               fine: bool) -> JointFit:
    """Minimise the sum of every pair's GICP cost (correspondences within ``distance_m``, m) from ``T``.

    ``clouds`` holds (source, target, target tree) as :func:`preprocess` makes them. Each iteration
    linearises every pair at ``T`` with small_gicp, sums ``H`` and ``b`` and takes the Gauss-Newton
    step ``T <- T exp(delta)``, ``delta = -H^-1 b`` (``[omega, v]``, source frame); it stops when the step
    is below the fine (or coarse) epsilons. A fine solve that ran out of iterations while its last step
    stayed within :data:`CYCLE_TOLERANCE` is taken as converged (alternating correspondence sets), with a note.
    """
    import small_gicp

    rotation_eps, translation_eps = (ROTATION_EPSILON_RAD, TRANSLATION_EPSILON_M) if fine else COARSE_EPSILON
    H, error, inliers, step, converged, iteration = np.zeros((6, 6)), 0.0, 0, np.zeros(6), False, 0
    for iteration in range(settings.max_iterations):
        H, b, error, inliers = np.zeros((6, 6)), np.zeros(6), 0.0, 0
        for source, target, tree in clouds:
            linearised = small_gicp.align(target, source, tree, init_T_target_source=T, registration_type="GICP",
                                          max_correspondence_distance=distance_m, num_threads=settings.num_threads,
                                          max_iterations=1)
            H += np.asarray(linearised.H)
            b += np.asarray(linearised.b).ravel()
            error += float(linearised.error)
            inliers += int(linearised.num_inliers)
        if inliers < 6 or not np.isfinite(H).all():
            return JointFit(T, H, error, inliers, iteration, False)
        step = np.linalg.lstsq(H, -b, rcond=None)[0]
        T = T @ vtf.SE3.exp(np.r_[step[3:], step[:3]]).as_matrix()
        if np.linalg.norm(step[:3]) <= rotation_eps and np.linalg.norm(step[3:]) <= translation_eps:
            converged = True
            break
    note = None
    dt, dr = float(np.linalg.norm(step[3:])), float(np.linalg.norm(step[:3]))
    if fine and not converged and dt < CYCLE_TOLERANCE[0] and dr < CYCLE_TOLERANCE[1]:
        converged = True
        note = (f"the joint fine GICP alternates between correspondence sets (last step {dt * 1000:.2f} mm, "
                f"{np.degrees(dr):.4f} deg); taken as converged")
    return JointFit(T, H, error, inliers, iteration + 1, converged, note)


def _refine(pairs: list[_Pair], T: np.ndarray, settings: LidarLidarSettings,
            progress: ProgressCallback = no_progress) -> JointFit:
    """The coarse stages (if ``settings.coarse_to_fine``), then the fine one, of the joint objective over ``pairs``."""
    if settings.coarse_to_fine:
        for distance in settings.coarse_max_correspondence_m:
            progress(0.1, f"joint coarse GICP over {len(pairs)} pairs ({distance} m correspondences)")
            T = joint_gicp([p.coarse for p in pairs], T, settings, distance, fine=False).T_target_source
    progress(0.2, f"joint fine GICP over {len(pairs)} pairs ({settings.max_correspondence_m} m correspondences)")
    return joint_gicp([p.fine for p in pairs], T, settings, settings.max_correspondence_m, fine=True)


def _quality(pairs: list[_Pair], T: np.ndarray, settings: LidarLidarSettings) -> dict[str, Any]:
    """Mean fitness over ``pairs`` and the statistics of all their inlier distances (see :func:`evaluate_alignment`)."""
    qualities = [evaluate_alignment(p.source, p.target, T, settings.max_correspondence_m,
                                    num_threads=settings.num_threads) for p in pairs]
    return {"fitness": float(np.mean([q["fitness"] for q in qualities])),
            **distance_statistics(np.concatenate([q["distances_m"] for q in qualities]))}


def _sectors(pairs: list[_Pair], T: np.ndarray, settings: LidarLidarSettings,
             progress: ProgressCallback) -> np.ndarray | None:
    """The azimuth-sector jackknife std (6,) of the joint fine solve over ``pairs`` about ``T`` (m, rad)."""
    targets = [p.fine[1:] for p in pairs]
    return sector_jackknife([p.source for p in pairs], lambda kept: joint_gicp(
        [(k, *t) for k, t in zip(kept, targets, strict=True)], T, settings, settings.max_correspondence_m,
        fine=True).T_target_source, T, settings, progress)


def _solve_scene(pairs: list[_Pair], indices: list[int], T_init: np.ndarray, settings: LidarLidarSettings,
                 progress: ProgressCallback) -> SceneResult:
    """One scene's own solve, from the same initial guess as the joint one, with its sector-widened sigma."""
    chosen = [pairs[i] for i in indices]
    fit = _refine(chosen, T_init, settings)
    T = fit.T_target_source
    quality = _quality(chosen, T, settings)
    ok = not fit_warnings(quality["fitness"], fit.converged, settings)
    cov = hessian_covariance(fit, T)
    if settings.spread and ok:
        cov = widen_covariance(cov, _sectors(chosen, T, settings, progress))
    return SceneResult(indices, T, quality["fitness"], quality["rmse_m"], ok, cov)


def register_pairs(pairs: list[tuple[np.ndarray, np.ndarray]], T_init: np.ndarray | None = None,
                   settings: LidarLidarSettings | None = None, progress: ProgressCallback = no_progress,
                   names: list[tuple[str, str]] | None = None) -> TransformResult:
    """One ``T_target_source`` (maps source points into the target frame) from several (source, target) frame
    pairs (N, 3 arrays, m, sensor frames) of a rig whose LiDARs did not move between them: a
    :class:`TransformResult` (``parent`` "target", ``child`` "source") whose diagnostics hold every scene's own
    solve (see :func:`backend.calib.lidar_lidar.gicp.assemble_result`).

    The pairs are solved jointly (:func:`joint_gicp`) from ``T_init`` (or from global registration on the
    first pair), grouped into scenes by their target clouds (:func:`~backend.core.clouds.group_by_place`), and every
    scene is solved on its own for the cross-check (see the module docstring). One pair is :func:`register_pair`.
    ``names`` are the (source, target) names of each pair's clouds (files, capture ids) for messages; default
    ``pair i source`` / ``pair i target``. Raises :class:`InputError` naming the cloud for a bad one, and for a
    non-rigid ``T_init``.
    """
    settings = settings or LidarLidarSettings()
    if not pairs:
        raise InputError("no frame pairs given", "pairs")
    names = names or [(f"pair {i} source", f"pair {i} target") for i in range(len(pairs))]
    if len(pairs) == 1:
        return register_pair(pairs[0][0], pairs[0][1], T_init, settings, progress, *names[0])
    started = time.perf_counter()
    warnings: list[str] = []
    checked = []
    for (source_points, target_points), (source_name, target_name) in zip(pairs, names, strict=True):
        (source, dropped_s), (target, dropped_t) = (check_cloud(source_points, source_name),
                                                    check_cloud(target_points, target_name))
        warnings += [f"{name}: dropped {n} non-finite points"
                     for name, n in ((source_name, dropped_s), (target_name, dropped_t)) if n]
        checked.append((source, target))
    T_init, init_method = initial_guess(T_init, *checked[0], settings, progress, warnings)
    progress(0.05, f"preprocessing {len(pairs)} frame pairs")
    prepared = [_prepare(s, t, settings) for s, t in checked]
    groups = group_by_place([np.asarray(p.fine[1].points())[:, :3] for p in prepared], settings.voxel_m)

    fit = _refine(prepared, T_init, settings, progress)
    T = fit.T_target_source
    warnings += [fit.note] if fit.note else []
    quality = _quality(prepared, T, settings)
    problems = fit_warnings(quality["fitness"], fit.converged, settings)
    warnings += problems
    ok = not problems
    cov_h = hessian_covariance(fit, T)
    std_spread = None
    if len(groups) == 1:
        if settings.spread and ok:
            std_spread = _sectors(prepared, T, settings, progress)
        covariance = widen_covariance(cov_h, std_spread)
        scenes = [SceneResult(groups[0], T, quality["fitness"], quality["rmse_m"], ok, covariance)]
    else:
        scenes = []
        for k, indices in enumerate(groups):
            def scene_progress(fraction: float, message: str, k: int = k) -> None:
                progress(0.3 + 0.6 * (k + fraction) / len(groups), f"scene {k + 1} of {len(groups)}: {message}")

            scenes.append(_solve_scene(prepared, indices, T_init, settings, scene_progress))
        progress(0.9, "leaving each scene out in turn")
        others = [joint_gicp([p.fine for i, p in enumerate(prepared) if i not in indices], T, settings,
                             settings.max_correspondence_m, fine=True) for indices in groups]
        for scene, other in zip(scenes, others, strict=True):
            T_other = other.T_target_source
            scene.deviation = params_between(T_other, scene.T_target_source)
            combined = np.diag(scene.covariance) + np.diag(hessian_covariance(other, T_other))
            scene.allowance = np.fmax(TOLERANCE, CROSS_CHECK_SIGMAS * np.sqrt(np.nan_to_num(combined, nan=np.inf)))
        if settings.spread and ok:
            std_spread = jackknife_std(np.array([params_between(T, o.T_target_source) for o in others]))
        covariance = widen_covariance(cov_h, std_spread)

    judge = judge_fit(transform_std(covariance), quality["fitness"], ok, problems, settings)
    if len(groups) == 1:
        judge_one_scene(judge, SECTORS if std_spread is not None else None, frames=len(pairs))
    else:
        scenes_cross_check(judge, scenes)
    progress(1.0, "done")
    return assemble_result(T, quality, covariance, cov_h, std_spread, "sectors" if len(groups) == 1 else "scenes",
                           settings, ok, started, (T_init, init_method), fit, judge.verdict(), scenes, warnings)
