"""Levenberg-Marquardt for bundle problems: parameters every view shares, and a 6-parameter pose per view.

Written by hand because SciPy's solvers do not use a bundle's structure: each step here solves the damped normal
equations with the poses eliminated (the Schur complement: a small system in the shared parameters, then each pose
alone). The photogrammetric bundle adjustment (:mod:`backend.calib.intrinsics.photogrammetric`) and the V-target
LiDAR-camera solve (:mod:`backend.calib.lidar_camera.v_target`, its camera poses held by their priors) run on it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Evaluate = Callable[[np.ndarray], tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]]
"""``evaluate(params)``: per view, its residuals (n_v,), their Jacobian by the shared parameters (n_v, n_shared)
and by the view's own pose (n_v, 6)."""
MAX_ITERATIONS = 100
"""Most Levenberg-Marquardt steps of one solve."""
RELATIVE_DECREASE = 1e-12
"""The solve stops when an accepted step lowers the cost by less than this fraction."""


def levenberg_marquardt(evaluate: Evaluate, start: np.ndarray, n_interior: int) -> np.ndarray:
    """Minimise the sum of squared residuals over ``[interior (n_interior), pose_1 (6), ..., pose_V (6)]``.

    ``evaluate(params)`` gives each view's residuals and its Jacobians by the parameters all views share (the
    "interior" ones: a camera's interior orientation, a LiDAR's extrinsic) and by its own pose. Each step solves
    the damped normal equations with the poses eliminated (the Schur complement, a small system in the interior
    parameters), then each pose alone, so a step
    costs a few small solves rather than a QR of the whole (views x 6 + 10)-column Jacobian (MINPACK's, which took
    about 1 s a solve at 48 views and made the view jackknife of a photogrammetric result a minute long). Damping
    is Marquardt's (the normal matrix's diagonal), the system scaled to unit diagonal before solving, since ``c``
    (~1e3 px) and ``K3`` (~1e-18 px^-6) differ by twenty orders.
    """
    x = start.copy()
    residuals, interior, pose = evaluate(x)
    cost = sum(float(r @ r) for r in residuals)
    damping = 1e-3
    for _ in range(MAX_ITERATIONS):
        H_aa = sum(a.T @ a for a in interior) if n_interior else np.zeros((0, 0))
        g_a = sum(a.T @ r for a, r in zip(interior, residuals, strict=True)) if n_interior else np.zeros(0)
        H_ap = [a.T @ p for a, p in zip(interior, pose, strict=True)]
        H_pp = [p.T @ p for p in pose]
        g_p = [p.T @ r for p, r in zip(pose, residuals, strict=True)]
        while True:
            inverses = [np.linalg.inv(H + damping * np.diag(np.diag(H))) for H in H_pp]
            step_a = np.zeros(n_interior)
            if n_interior:
                S = H_aa + damping * np.diag(np.diag(H_aa)) - sum(h @ inv @ h.T for h, inv in zip(H_ap, inverses,
                                                                                                  strict=True))
                b = -g_a + sum(h @ inv @ g for h, inv, g in zip(H_ap, inverses, g_p, strict=True))
                scale = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
                step_a = scale * np.linalg.solve(S * np.outer(scale, scale), b * scale)
            step_p = [inv @ (-g - h.T @ step_a) for inv, g, h in zip(inverses, g_p, H_ap, strict=True)]
            trial = x + np.concatenate([step_a, *step_p])
            trial_residuals, trial_interior, trial_pose = evaluate(trial)
            trial_cost = sum(float(r @ r) for r in trial_residuals)
            if trial_cost < cost:
                break
            damping *= 4.0
            if damping > 1e12:
                return x
        decrease = (cost - trial_cost) / max(cost, 1e-300)
        x, residuals, interior, pose, cost = trial, trial_residuals, trial_interior, trial_pose, trial_cost
        damping = max(damping / 3.0, 1e-12)
        if decrease < RELATIVE_DECREASE:
            break
    return x


def shared_covariance(interior: list[np.ndarray], pose: list[np.ndarray]) -> np.ndarray:
    """``(J^T J)^-1``'s block of the shared parameters, from the per-view Jacobians at a solution: the inverse of
    the Schur complement ``H_aa - sum H_ap H_pp^-1 H_pa`` (residuals in their sigmas); NaN when singular."""
    schur = sum(a.T @ a - (a.T @ p) @ np.linalg.inv(p.T @ p) @ (p.T @ a) for a, p in zip(interior, pose, strict=True))
    try:
        return np.linalg.inv(schur)
    except np.linalg.LinAlgError:
        return np.full(schur.shape, np.nan)
