"""Which lens model to solve with: candidates compared by their reprojection error on held-out views.

Each candidate is fitted on all but one fold of the views and tested on the views it did not see (each
held-out view gets its own pose by PnP with the fitted intrinsics, then its corners' RMS): a model with
more coefficients always fits its own views better, but only a model that follows the lens also predicts
new ones. The recommendation is the simplest candidate whose held-out RMS is within
:data:`WITHIN_BEST` of the best output model's; the photogrammetric model (ten parameters, affine terms
included) and mrcal's splined model (hundreds of spline values, so it wins only where it predicts clearly better) are
candidates only where no export is named, since ROS and Kalibr cannot carry them. OpenCV's
rational model (8 coefficients) is compared too, but it is not an output model here (no export or
projection carries it), so it can only be reported.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from backend.calib.board.pose import board_pose
from backend.calib.intrinsics import photogrammetric
from backend.calib.intrinsics.checks import intrinsics_verdict
from backend.calib.intrinsics.flex import refine_with_flex
from backend.calib.intrinsics.projection import project_board
from backend.calib.intrinsics.solver import (
    TERM_CRITERIA,
    IntrinsicsResult,
    IntrinsicsSettings,
    View,
    _calibrate,
    _check_views,
    _pick_corners,
    _resolved_spline,
    calibrate_intrinsics,
    planar_start,
)
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.transforms import to_rvec_tvec

MIN_VIEWS_TO_COMPARE = 8
"""Fewest views for the comparison: each of the :data:`FOLDS` fits keeps at least 6 views."""
FOLDS = 4
"""Views are dealt round-robin into this many folds; each is held out once."""
WITHIN_BEST = 0.05
"""A simpler model is preferred while its held-out RMS is at most this fraction above the best's."""
SIMPLE = "pinhole-radtan k1-k2"
"""The model kept when the views are too few to compare."""
EXPORT_MODELS: dict[str, frozenset[str]] = {
    "any": frozenset({SIMPLE, "fisheye-equidistant", "pinhole-radtan k1-k3", "photogrammetric",
                      "splined-stereographic"}),
    "camera_info": frozenset({SIMPLE, "fisheye-equidistant", "pinhole-radtan k1-k3"}),
    "kalibr": frozenset({SIMPLE, "fisheye-equidistant"}),
}
"""The output models each export carries (``IntrinsicsSettings.auto_for``): ROS's camera_info holds plumb_bob
(k1, k2, p1, p2, k3) and equidistant; Kalibr's camchain radtan (k1, k2, p1, p2) and equidistant, no k3."""


@dataclass(frozen=True)
class Candidate:
    """A lens model to compare: its name, the solve settings (None: OpenCV's rational model) and parameters."""

    name: str
    settings: IntrinsicsSettings | None
    n_dist: int
    """Distortion coefficients it estimates (its complexity; fewer wins a tie)."""


def candidates(base: IntrinsicsSettings, spline: IntrinsicsSettings | None = None) -> list[Candidate]:
    """The compared models, simplest first; ``base`` gives the shared options (tangential, aspect), ``spline`` the
    splined model's settings with its knots set (:func:`~backend.calib.intrinsics.solver._resolved_spline`; None:
    not compared)."""
    radtan = replace(base, model="pinhole-radtan", jackknife=False, cross_validate=False, drop_outliers=False)
    tangential = 2 if base.estimate_tangential else 0
    splined = ([] if spline is None else
               [Candidate("splined-stereographic", replace(spline, jackknife=False, cross_validate=False,
                                                           drop_outliers=False), spline.spline.n_control)])
    return [
        Candidate(SIMPLE, replace(radtan, estimate_k3=False), 2 + tangential),
        Candidate("fisheye-equidistant", replace(radtan, model="fisheye-equidistant"), 4),
        Candidate("pinhole-radtan k1-k3", replace(radtan, estimate_k3=True), 3 + tangential),
        Candidate("photogrammetric", replace(radtan, model="photogrammetric"), len(photogrammetric.INTERIOR) - 3),
        Candidate("pinhole-rational", None, 6 + tangential),
        *splined,
    ]


def _fit(candidate: Candidate, views: list[View], board: BoardSpec, size: tuple[int, int],
         base: IntrinsicsSettings) -> tuple[np.ndarray, np.ndarray]:
    """K and dist of ``candidate`` fitted on ``views`` (the splined model's control points as its dist)."""
    if candidate.settings is not None:
        K, dist, *_ = _calibrate(views, board, size, candidate.settings)
        return K, dist
    flags = (cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_ZERO_TANGENT_DIST * (not base.estimate_tangential)
             | cv2.CALIB_FIX_ASPECT_RATIO * base.fix_aspect)
    K_start = planar_start(views, board, size)
    flags |= cv2.CALIB_USE_INTRINSIC_GUESS * (K_start is not None)
    _, K, dist, _, _ = cv2.calibrateCamera([v.detection.object_points(board) for v in views],
                                           [v.detection.corners_px.astype(np.float32) for v in views], size,
                                           np.eye(3) if K_start is None else K_start, None, flags=flags,
                                           criteria=TERM_CRITERIA)
    return K, dist.ravel()[:8]


def _held_out_residuals(settings: IntrinsicsSettings, K: np.ndarray, dist: np.ndarray, view: View,
                        board: BoardSpec, size: tuple[int, int]) -> np.ndarray:
    """(N, 2) residuals (px) of a view the model of ``settings`` was not fitted on, posed by PnP with the fitted
    intrinsics (for the photogrammetric and splined models: PnP on the undistorted corners, then refined in
    pixels)."""
    model = settings.model
    obj = view.detection.object_points(board).astype(np.float64).reshape(-1, 1, 3)
    img = view.detection.corners_px.reshape(-1, 1, 2)
    if model == "splined-stereographic":
        camera = settings.camera(size, K, dist)
        T = board_pose(camera, board, view.detection)
        if T is None:
            raise InputError(f"{view.name}: the held-out view could not be posed", view.name)
        rvec, tvec = to_rvec_tvec(T)
        *_, rvecs, tvecs, _ = refine_with_flex(camera, np.zeros((len(camera.parameters), 0)), board,
                                               [view.detection], [rvec], [tvec], solve_flex=False)
        return img.reshape(-1, 2) - project_board(camera, obj, rvecs[0], tvecs[0])[0]
    if model == "photogrammetric":
        camera = CameraIntrinsics(model, size[0], size[1], K, dist)
        T = board_pose(camera, board, view.detection)
        if T is None:
            raise InputError(f"{view.name}: the held-out view could not be posed", view.name)
        rvec, tvec = cv2.Rodrigues(T[:3, :3])[0], T[:3, 3:]
        _, _, rvecs, tvecs = photogrammetric.bundle_adjust(camera, [obj], [img], [rvec], [tvec], fix_interior=True)
        return img.reshape(-1, 2) - photogrammetric.project(camera, obj, rvecs[0], tvecs[0])[0]
    if model == "fisheye-equidistant":
        _, rvec, tvec = cv2.fisheye.solvePnP(obj, img, K, dist[:4], flags=cv2.SOLVEPNP_ITERATIVE)
        projected, _ = cv2.fisheye.projectPoints(obj, rvec, tvec, K, dist[:4])
    else:
        _, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        projected, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    return img.reshape(-1, 2) - projected.reshape(-1, 2)


def _held_out_rms(candidate: Candidate, views: list[View], board: BoardSpec, size: tuple[int, int],
                  base: IntrinsicsSettings) -> dict[str, Any]:
    """``{"model", "n_dist", "held_out_rms_px"}`` over :data:`FOLDS` folds, or with ``error`` if a fit failed."""
    residuals = []
    settings = candidate.settings or replace(base, model="pinhole-radtan")
    try:
        for fold in range(FOLDS):
            train = [v for i, v in enumerate(views) if i % FOLDS != fold]
            K, dist = _fit(candidate, train, board, size, base)
            residuals += [_held_out_residuals(settings, K, dist, v, board, size)
                          for i, v in enumerate(views) if i % FOLDS == fold]
    except (InputError, cv2.error, ValueError) as exc:  # ValueError: a fitted spline that folds over a view
        message = exc.message if isinstance(exc, InputError) else getattr(exc, "err", str(exc))
        return {"model": candidate.name, "n_dist": candidate.n_dist, "held_out_rms_px": None, "error": message}
    r = np.concatenate(residuals)
    return {"model": candidate.name, "n_dist": candidate.n_dist,
            "held_out_rms_px": float(np.sqrt(np.mean(np.sum(r**2, axis=1))))}


def compare_models(views: list[View], board: BoardSpec, size: tuple[int, int],
                   base: IntrinsicsSettings) -> dict[str, Any]:
    """Compare the :func:`candidates` on held-out views and recommend one.

    Returns ``{"status": "compared" | "too few views", "recommended", "reason", "candidates": [...]}``;
    ``recommended`` is always an output model's name (:data:`SIMPLE` when the views are too few). The splined
    model is compared when ``base`` names no export and the views' corners can measure its knots (else its row
    says why not).
    """
    if len(views) < MIN_VIEWS_TO_COMPARE:
        return {"status": "too few views", "recommended": SIMPLE, "candidates": [],
                "reason": f"{len(views)} views; comparing models on held-out views needs at least "
                          f"{MIN_VIEWS_TO_COMPARE}, so the simple model {SIMPLE} is kept"}
    _check_views(views, board)
    spline, spline_row = None, []
    if base.auto_for == "any":
        try:
            spline = _resolved_spline(views, board, size, replace(base, model="splined-stereographic"))
        except InputError as exc:
            spline_row = [{"model": "splined-stereographic", "n_dist": None, "held_out_rms_px": None,
                           "error": exc.message}]
    rows = [_held_out_rms(c, views, board, size, base) for c in candidates(base, spline)] + spline_row
    scored = [r for r in rows if r["held_out_rms_px"] is not None]
    carried = EXPORT_MODELS[base.auto_for]
    outputs = [r for r in scored if r["model"] in carried]
    if not outputs:
        return {"status": "compared", "recommended": SIMPLE, "candidates": rows,
                "reason": f"no output model could be fitted on every fold; {SIMPLE} is kept"}
    best = min(outputs, key=lambda r: r["held_out_rms_px"])
    limit = best["held_out_rms_px"] * (1 + WITHIN_BEST)
    chosen = min((r for r in outputs if r["held_out_rms_px"] <= limit), key=lambda r: r["n_dist"])
    reason = (f"{chosen['model']}: held-out RMS {chosen['held_out_rms_px']:.3f} px, within {WITHIN_BEST:.0%} of the "
              f"best ({best['model']}, {best['held_out_rms_px']:.3f} px) with the fewest coefficients")
    if base.auto_for != "any":
        left_out = [r for r in scored if r["model"] not in carried and r["model"] != "pinhole-rational"]
        reason += f"; among the models {base.auto_for} carries" + "".join(
            f" ({r['model']}, {r['held_out_rms_px']:.3f} px, left out)" for r in left_out)
    worse = [r for r in outputs if r["n_dist"] < chosen["n_dist"]]
    if worse:
        reason += "; simpler: " + ", ".join(f"{r['model']} {r['held_out_rms_px']:.3f} px" for r in worse)
    rational = next((r for r in scored if r["model"] == "pinhole-rational"), None)
    if rational and rational["held_out_rms_px"] < chosen["held_out_rms_px"] / (1 + WITHIN_BEST):
        reason += (f"; the rational model predicts better still ({rational['held_out_rms_px']:.3f} px) but is "
                   "compared only, not an output model")
    for row in rows:
        row["recommended"] = row["model"] == chosen["model"]
    return {"status": "compared", "recommended": chosen["model"], "reason": reason, "candidates": rows}


def settings_for(recommended: str, base: IntrinsicsSettings) -> IntrinsicsSettings:
    """``base`` with the model (and k3) of a recommended output model's name."""
    if recommended in ("fisheye-equidistant", "photogrammetric", "splined-stereographic"):
        return replace(base, model=recommended)
    return replace(base, model="pinhole-radtan", estimate_k3=recommended == "pinhole-radtan k1-k3")


def solve_auto(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
               progress: ProgressCallback = no_progress) -> IntrinsicsResult:
    """:func:`calibrate_intrinsics`, first resolving ``settings.model == "auto"`` by :func:`compare_models`.

    The comparison runs on the corner set that fits the simple model better (:func:`_pick_corners`); the
    result carries it as ``model_comparison``.
    """
    if settings.model != "auto":
        return calibrate_intrinsics(views, board, size, settings, progress)
    progress(0.0, "comparing lens models on held-out views")
    _check_views(views, board)
    picked, _ = _pick_corners(views, board, size, settings_for(SIMPLE, settings))
    comparison = compare_models(picked, board, size, settings)
    result = calibrate_intrinsics(views, board, size, settings_for(comparison["recommended"], settings), progress)
    result.model_comparison = comparison
    result.verdict = intrinsics_verdict(result.projection_uncertainty, result.cross_validation, result.board_flex,
                                        result.jackknife, models_compared=True,
                                        splined=result.camera.spline is not None)
    return result
