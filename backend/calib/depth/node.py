"""A depth node's pose in the cell from what it sees of the cell's known geometry (issue 14's automatic solve).

The same evidence the guided procedure uses (:mod:`backend.calib.depth.guided`), solved for all six
degrees of freedom at once: the floor and every table top (``z = height`` for each of their points), the
tape lines (``x = value`` or ``y = value`` for each tape pixel) and surveyed crosses (a known point), from
any number of captures. SciPy's ``least_squares`` fits the 6-vector perturbation of
:func:`backend.core.transforms.apply_params` (translation in m along the world axes, rotation in rad
about the node's axes) with every residual divided by its 1-sigma (range noise; the tape's width) under
a soft-L1 loss, with an analytic Jacobian. The features are found again at the solved pose
(:func:`~backend.calib.depth.features.extract_features` with tight gates), as the association of tape
pixels to lines may change once the pose moves, and solved again.

Uncertainty: the Jacobian's covariance (the range noise and the tapes' width), plus what the pixel grid's
sampling of each tape line leaves open (:func:`_line_sampling_covariance`), widened by the leave-one-capture-out
jackknife spread (:func:`~backend.core.result.widen_covariance`). Verdict: those sigmas against
``translation_tolerance_m`` / ``rotation_tolerance_deg`` and, as the independent cross-checks, each held-out
capture's tables and lines at the pose solved without it, and the crosses seen (not used by the solve unless
surveyed) against their known positions.

Which evidence fixes what: horizontal planes (floor, tables) fix Z and the tilt (RotX, RotY); lines along
one axis fix that coordinate and the heading (RotZ); both axes' lines are needed for X and Y. A solve that
leaves a degree of freedom open raises :class:`InputError` naming it and what is missing.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from backend.calib.depth.checks import node_verdict
from backend.calib.depth.features import (
    AXES,
    DepthNodeSettings,
    DepthObservation,
    Feature,
    cross_centre,
    extract_features,
    feature_residuals,
    ranges_m,
)
from backend.core.depth import pose_row
from backend.core.depth_cell import CellLayout
from backend.core.errors import InputError
from backend.core.result import (
    ProgressCallback,
    TransformResult,
    finite_or_none,
    jackknife_std,
    jacobian_covariance,
    no_progress,
    transform_std,
    widen_covariance,
)
from backend.core.transforms import (
    apply_params,
    check_transform,
    invert,
    params_between,
    right_jacobian,
    transform_points,
)
from backend.core.uncertainty import sigmas

__all__ = ["DepthNodeSettings", "DepthObservation", "Feature", "extract_features", "feature_residuals",
           "solve_depth_node", "fit_features", "extract_all", "undetermined_parameters"]

POSE_PARAMETERS = ("X", "Y", "Z", "RotX", "RotY", "RotZ")
"""The pose's degrees of freedom as a person names them (the pose row's columns)."""
UNDETERMINED_TRANS_M = 0.05
UNDETERMINED_ROT_DEG = 0.5
"""A degree of freedom whose 1-sigma (from the evidence's information alone) exceeds these is not determined."""
CONVERGED_SHARE = 0.1
"""Extract-and-solve rounds stop once the pose moves less than this share of the tolerances between rounds."""


def _stack(features: list[Feature], layout: CellLayout, settings: DepthNodeSettings, T_world_node: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every point residual's node-frame point (M, 3), world axis (M, 3, unit), known value (M,, m), weight
    (M,, 1/m) and feature (M,, index into ``features``): planes constrain world z, lines x or y, a surveyed
    cross's centre all three (its :func:`cross_centre` found at ``T_world_node``, taken back to the node frame)."""
    points, axes, known, weights, owner = [], [], [], [], []
    for k, feature in enumerate(features):
        if feature.kind == "point":
            if not layout.cross(feature.name.removeprefix("cross ")).surveyed:
                continue  # a cross checks the solve; it constrains it only when surveyed
            centre = transform_points(invert(T_world_node), cross_centre(transform_points(T_world_node,
                                                                                          feature.points))[None])[0]
            points.append(np.repeat(centre[None], 3, axis=0))
            axes.append(np.eye(3))
            known.append(np.asarray(feature.known, dtype=float))
            weights.append(np.full(3, 1 / settings.point_sigma_m))
            owner.append(np.full(3, k))
            continue
        n = len(feature.points)
        axis = np.zeros(3)
        axis[AXES[feature.axis or "z"]] = 1.0
        sigma = settings.sigma_m(ranges_m(feature.points))
        if feature.kind == "line":
            sigma = np.hypot(sigma, settings.line_sigma_m)
        points.append(feature.points)
        axes.append(np.repeat(axis[None], n, axis=0))
        known.append(np.full(n, float(feature.known)))
        weights.append(1 / sigma)
        owner.append(np.full(n, k))
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    return (np.vstack(points), np.vstack(axes), np.concatenate(known), np.concatenate(weights),
            np.concatenate(owner))


def fit_features(features: list[Feature], T_world_node: np.ndarray, layout: CellLayout,
                 settings: DepthNodeSettings) -> tuple[np.ndarray, Any]:
    """``T_world_node`` (4x4, m) that best fits ``features`` from ``T_world_node``, and SciPy's result (its ``x`` the
    :func:`apply_params` step, its ``jac`` the loss-scaled Jacobian in sigma units with respect to the solution's
    own :data:`~backend.core.result.TRANSFORM_PARAMETERS`)."""
    P, A, K, W, _ = _stack(features, layout, settings, T_world_node)
    if len(P) < 6:
        raise InputError(f"{len(P)} constraints from the features seen; a pose needs at least 6", "features")
    R0 = T_world_node[:3, :3]

    # (M, 3) @ (3, 3) products go through einsum: OpenBLAS takes 20x longer for such thin matrices here
    def residuals(p: np.ndarray) -> np.ndarray:
        T = apply_params(T_world_node, p)
        return W * (np.einsum("ij,jk,ik->i", A, T[:3, :3], P) + A @ T[:3, 3] - K)

    def jacobian(p: np.ndarray) -> np.ndarray:
        # d/d dt: the axis; d/d dr (child axes): p x (M^T a) J_r(dr), M = R0 Exp(dr) (a . M (v x p) = v . (p x M^T a))
        M = R0 @ Rotation.from_rotvec(p[3:]).as_matrix()
        arms = np.cross(P, np.einsum("ij,jk->ik", A, M))
        return W[:, None] * np.hstack([A, np.einsum("ij,jk->ik", arms, right_jacobian(p[3:]))])

    fit = least_squares(residuals, np.zeros(6), jac=jacobian, loss="soft_l1", f_scale=settings.robust_scale,
                        x_scale="jac", method="trf")
    # the Jacobian in the solution's own parameters (rotation about its axes): J_r(x)^-1 turns the step's
    fit.jac = np.hstack([fit.jac[:, :3], fit.jac[:, 3:] @ np.linalg.inv(right_jacobian(fit.x[3:]))])
    return apply_params(T_world_node, fit.x), fit


def extract_all(observations: list[DepthObservation], T_world_node: np.ndarray, layout: CellLayout,
                settings: DepthNodeSettings) -> tuple[list[Feature], list[str]]:
    """:func:`extract_features` of every capture at one pose: all features and all problems."""
    features, problems = [], []
    for obs in observations:
        found, trouble = extract_features(obs, T_world_node, layout, settings)
        features += found
        problems += trouble
    return features, problems


def undetermined_parameters(fit: Any, T_world_node: np.ndarray) -> list[str]:
    """The pose parameters (:data:`POSE_PARAMETERS`) the fit's evidence leaves open.

    The fit's information ``J^T J`` (sigma units) is turned to the person's axes: translation along the
    world axes, rotation about the node's X and Y once turned by its heading (the tilts RotX, RotY) and about
    the world vertical (RotZ); a parameter whose marginal 1-sigma, from a slightly regularised inverse, is
    above :data:`UNDETERMINED_TRANS_M` or :data:`UNDETERMINED_ROT_DEG` is open."""
    R = T_world_node[:3, :3]
    heading = np.arctan2(R[1, 0], R[0, 0])
    c, s = np.cos(heading), np.sin(heading)
    basis = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # tilt axes and the vertical, world
    to_child = np.eye(6)
    to_child[3:, 3:] = R.T @ basis  # child-axis rotation = R^T (world rotation)
    J = fit.jac @ to_child
    std = sigmas(np.linalg.inv(J.T @ J + 1e-6 * np.eye(6)))
    limit = np.r_[np.full(3, UNDETERMINED_TRANS_M), np.full(3, np.radians(UNDETERMINED_ROT_DEG))]
    return [name for name, value, most in zip(POSE_PARAMETERS, std, limit, strict=True) if value > most]


def _undetermined_message(node: str, missing: list[str], features: list[Feature], layout: CellLayout) -> str:
    """Why ``missing`` parameters are open, from what was seen: "no floor line seen: X, Y and RotZ are not
    determined"."""
    axes_seen = {f.axis for f in features if f.kind == "line"}
    surveyed = [f for f in features if f.kind == "point" and layout.cross(f.name.removeprefix("cross ")).surveyed]
    reasons = []
    if {"X", "Y", "RotZ"} & set(missing):
        if not axes_seen and not surveyed:
            reasons.append("no floor line seen")
        else:
            for axis in ("x", "y"):
                if axis.upper() in missing and axis not in axes_seen:
                    others = sorted({ln.label for ln in layout.lines if ln.axis != axis} & {
                        ln.label for f in features if f.kind == "line" for ln in layout.lines if ln.name == f.name})
                    reasons.append(f"no floor line {axis.upper()} = const seen (only {', '.join(others) or 'points'})")
            if "RotZ" in missing and axes_seen:
                reasons.append("the lines seen are too short to fix the heading")
    if {"Z", "RotX", "RotY"} & set(missing):
        planes = [f for f in features if f.kind in ("floor", "table")]
        reasons.append("no floor or table seen" if not planes else
                       f"the {len(planes)} horizontal planes seen do not fix the tilt (too small or all at one place)")
    names = ", ".join(missing[:-1]) + (" and " if len(missing) > 1 else "") + missing[-1]
    verb = "are" if len(missing) > 1 else "is"
    return f"node {node}: {'; '.join(reasons) or 'the evidence is degenerate'}: {names} {verb} not determined"


def _line_sampling_covariance(features: list[Feature], layout: CellLayout, J: np.ndarray, W: np.ndarray,
                              owner: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """6x6 covariance (TRANSFORM_PARAMETERS) of the pose from where the pixels fell on each tape line.

    A line's pixels sample its width at the pixel grid's phase; when the line runs along the image's
    rows or columns that phase hardly changes along it, and its points' mean is off the centre by up to
    a pixel's footprint, the same for every point (no averaging takes it out). The points' offsets then
    span less than the tape's width: the centre is known only within the gap, ``width - span``, uniformly
    (1-sigma ``gap / sqrt(12)``). Each line's such shift moves the pose by ``(J^T J)^-1 J_f^T W_f`` per metre
    (``J`` the fit's Jacobian in sigma units, ``W`` the rows' weights, 1/m, ``offsets`` their residuals, m)."""
    covariance = np.zeros((6, 6))
    if not any(f.kind == "line" for f in features):
        return covariance
    try:
        inverse = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return covariance
    widths = {line.name: line.width_m for line in layout.lines}
    for k, feature in enumerate(features):
        mine = owner == k
        if feature.kind != "line" or mine.sum() < 2:
            continue
        low, high = np.percentile(offsets[mine], [0.5, 99.5])
        sigma_m = max(widths[feature.name] - (high - low), 0.0) / np.sqrt(12)
        shift = inverse @ (J[mine].T @ W[mine])
        covariance += sigma_m**2 * np.outer(shift, shift)
    return covariance


def _held_out(observations: list[DepthObservation], features: list[Feature], T: np.ndarray, layout: CellLayout,
              settings: DepthNodeSettings) -> tuple[np.ndarray | None, list[dict]]:
    """Leave-one-capture-out: the jackknife 1-sigma (6,, m and rad) of the solves without each capture, and each
    held-out capture's table and line residuals at the pose solved without it. None and [] for one capture."""
    ids = [obs.capture_id for obs in observations]
    if len(set(ids)) < 2:
        return None, []
    steps, held = [], []
    for capture in dict.fromkeys(ids):
        kept = [f for f in features if f.capture_id != capture]
        T_without, _ = fit_features(kept, T, layout, settings)
        steps.append(params_between(T, T_without))
        rows = [row for row in feature_residuals([f for f in features if f.capture_id == capture], T_without)
                if row["kind"] in ("table", "line")]
        held.append({"capture_id": capture, "max_error_m": max((abs(r["error_m"]) for r in rows), default=None),
                     "features": rows})
    return jackknife_std(np.array(steps)), held


def solve_depth_node(node: str, observations: list[DepthObservation], layout: CellLayout,
                     T_world_node_init: np.ndarray, settings: DepthNodeSettings | None = None,
                     progress: ProgressCallback = no_progress) -> TransformResult:
    """``T_world_node`` of ``node`` from its captures, as a :class:`TransformResult` (``kind`` "depth_node",
    ``method`` "constraints", ``parent`` "world", ``child`` the node) with a 6x6 covariance and a verdict.

    ``T_world_node_init`` is the typed (tape-measured) pose, good to about ``settings.guess_trans_m`` and
    ``guess_rot_deg``. ``residuals``: ``rms_m`` over all points, ``plane_rms_m``, ``line_rms_m``, ``n_points``,
    ``n_features``, ``n_captures``; ``diagnostics``: every feature's :func:`feature_residuals` at the solution,
    the ``initial`` and solved ``pose_row``, the held-out captures, the crosses, the ``problems`` met, the rounds.
    Raises :class:`InputError` without captures, with nothing found in them, or when the evidence leaves a
    degree of freedom open (the message names it and what is missing)."""
    started = time.perf_counter()
    settings = settings or DepthNodeSettings()
    if not observations:
        raise InputError(f"node {node}: no captures to solve from; capture the node first", "observations")
    T_init, _ = check_transform(T_world_node_init, "T_world_node_init")
    T, fit, rounds = T_init, None, 0
    for rounds in range(1, settings.rounds + 1):
        progress(0.7 * (rounds - 1) / settings.rounds, f"finding the features (round {rounds})")
        features, problems = extract_all(observations, T, layout, settings if rounds == 1 else settings.refined())
        if not any(f.kind != "point" for f in features):
            raise InputError(f"node {node}: nothing to solve from: {'; '.join(problems) or 'no features found'}",
                             "observations")
        T_previous = T
        T, fit = fit_features(features, T, layout, settings)
        missing = undetermined_parameters(fit, T)
        if missing:  # checked every round: an open direction lets the solve wander, and the next round see nothing
            raise InputError(_undetermined_message(node, missing, features, layout), "observations")
        step_m, step_deg = np.split(params_between(T_previous, T), 2)
        if rounds > 1 and np.linalg.norm(step_m) < CONVERGED_SHARE * settings.translation_tolerance_m and \
                np.degrees(np.linalg.norm(step_deg)) < CONVERGED_SHARE * settings.rotation_tolerance_deg:
            break
    progress(0.75, "leave-one-capture-out solves")
    P, A, K, W, owner = _stack(features, layout, settings, T)
    offsets = np.einsum("ij,jk,ik->i", A, T[:3, :3], P) + A @ T[:3, 3] - K
    kinds = np.array([f.kind for f in features])[owner]
    cov_jacobian = jacobian_covariance(fit)
    cov_sampling = _line_sampling_covariance(features, layout, fit.jac, W, owner, offsets)
    spread, held = _held_out(observations, features, T, layout, settings)
    covariance = widen_covariance(cov_jacobian + cov_sampling, spread)
    rows = feature_residuals(features, T)
    crosses = [row for row in rows if row["kind"] == "point"]
    is_line, is_plane = kinds == "line", np.isin(kinds, ("floor", "table"))
    n_captures = len({obs.capture_id for obs in observations})
    unsurveyed = [row for row in crosses if not layout.cross(row["name"].removeprefix("cross ")).surveyed]
    verdict = node_verdict(transform_std(covariance), bool(fit.status > 0), held, unsurveyed, n_captures, settings)
    progress(1.0, "done")
    return TransformResult(
        kind="depth_node", method="constraints", parent="world", child=node, T_parent_child=T,
        covariance=covariance,
        residuals={"rms_m": float(np.sqrt(np.mean(offsets**2))),
                   "plane_rms_m": float(np.sqrt(np.mean(offsets[is_plane] ** 2))) if is_plane.any() else None,
                   "line_rms_m": float(np.sqrt(np.mean(offsets[is_line] ** 2))) if is_line.any() else None,
                   "n_points": int(len(P)), "n_features": len(features), "n_captures": n_captures},
        diagnostics={"features": rows, "initial": list(pose_row(T_init)), "pose_row": list(pose_row(T)),
                     "held_out": held, "crosses": crosses, "problems": problems, "rounds": rounds,
                     "std_jacobian": finite_or_none(sigmas(cov_jacobian)),
                     "std_line_sampling": finite_or_none(sigmas(cov_sampling)),
                     "std_spread": finite_or_none(spread)},
        settings=asdict(settings), converged=bool(fit.status > 0), verdict=verdict, warnings=list(problems),
        seconds=time.perf_counter() - started)
