#!/usr/bin/env python
"""Intrinsics against mrcal: the studio's solve and mrcal's on the very same corners, per real set.

Sets: ``opencv_left`` / ``opencv_right`` (OpenCV's 640x480 stereo chessboard images, 9x6 inner corners, 25 mm)
and ``vlp16_wide`` (the VLP-16 rig's 1920x1020 wide-angle camera, 8 views of a 7x6, 50 mm board).

Corners: ``detect_board`` finds them once; the studio's solve picks its corner set (the detector's own or a
refinement, ``corners`` in its result) and mrcal is given exactly that set, written as mrcal's corners cache
(``filename x y level``, one row per corner in mrcal's grid order: rows of ``object-width-n`` points along the
board's x, the studio's row-major ids; a corner the detector dropped is a ``- - -`` row). mrcal's plain fit
landing on the studio's RMS (ratio ~1) is the check that the order is right.

Solves:

- ``ours``: :func:`calibrate_intrinsics` with ``pinhole-radtan`` and k3 (mrcal's ``LENSMODEL_OPENCV5``), free
  aspect as mrcal has it, the defaults otherwise (the board's flex solved, corner rejection and the jackknife on),
  cross-validation off (it does not change the sigma). Its ``projection_sigma_px`` is the result's, mrcal's way
  (the camera free to turn against the boards); ``jackknife_projection_max_px`` the jackknife's (the intrinsics
  alone propagated), reported beside it as a cross-check; ``flat`` the same solve with the board held flat;
  ``splined`` the studio's ``splined-stereographic`` solve (the defaults, flex and rejection) with the set's knots
  and field of view.
- mrcal, through Debian's ``mrcal-calibrate-cameras`` (the studio's venv cannot import mrcal), three ways:
  ``a_opencv5_plain``: ``LENSMODEL_OPENCV5`` with no board flex, no outlier rejection and no regularization, the
  closest mrcal gets to the studio's solve; ``b_opencv5_flex_outliers``: the same model mrcal's default way,
  ``calobject_warp`` solved and outliers rejected; ``c_splined``: ``LENSMODEL_SPLINED_STEREOGRAPHIC`` order 3
  (:data:`SETS` gives the knots and field of view of each set, and why).

Figures per solve: ``rms_px`` (RMS over the corners kept of the corner's residual length, the studio's
definition; mrcal's own printout is per coordinate, 1/sqrt(2) of this), ``corners_rejected``,
``calobject_warp_mm`` (mrcal's maximum deflection at the board's centre along its x and its y), the worst-direction
projection sigma (px) of a point at infinity at the centre cell and the worst over the studio's 16x9 grid of
cells (the studio's figure is defined at infinity with the intrinsics' covariance alone; mrcal's is
``mrcal.projection_uncertainty(..., atinfinity=True)``, which also propagates the board poses' rotations), and
``seconds`` (the studio's solve; mrcal's whole command, Python start-up included). Each mrcal solve also gives
``max_projection_difference_px``: over the grid cells, how far mrcal's model puts the far point the studio's
model sees at the cell's centre (no rotation fitted between them), the like-for-like check for ``a``.

A fitted polynomial can fold back beyond its data (on the wide lens, OPENCV5 does): grid cells where a model does
not invert are counted (``grid_cells_not_inverted``) and left out of that difference and of each side's
``worst_where_inverted`` (the studio's) or ``worst`` (mrcal's, whose unprojection gives up there); the studio's
``worst`` is its result's, over the whole grid.

Ratios are ours / mrcal's, for RMS and the sigmas (reported and analytic; worst over the cells each model
inverts), against ``a`` and ``b``, and our splined solve against ``c``. When Debian's mrcal is missing the
JSON says ``"mrcal": "not installed"`` and carries the studio's figures alone.

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/intrinsics_vs_mrcal.py
"""

import json
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from bench_util import log

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.crossval import grid_pixels
from backend.calib.intrinsics.solver import UNCERTAINTY_GRID, IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.splined import SplineGrid

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
MRCAL_PYTHON = "/usr/bin/python3"
ROUND_TRIP_PX = 0.01
"""A grid cell where the studio's model projects its own unprojection further than this (px) is not inverted."""


@dataclass
class CalibrationSet:
    name: str
    folder: str
    pattern: str
    board: str
    spline: str
    """mrcal's splined model for the set. Order 3 puts the field of view's edge on the second knot from each end and
    keeps the knots square, so ``Ny - 3`` over ``Nx - 3`` knot spans must cover the image's height over its width in
    stereographic coordinates."""


SETS = (
    # 640x480: the studio's fit sees the image's edges at 32-36 deg off-axis (stereographic |u| up to 0.65 across,
    # 0.46 down, ratio 0.71), so 80 deg across with 12x10 knots (7/9 = 0.78) covers the whole image. 13 views of 54
    # corners give 1,404 measurements for 240 spline values: the 16x10 would need a wider field than the lens
    # (10 knot rows cover 7/13 of the width) and leaves more knots without a corner near them.
    CalibrationSet("opencv_left", "opencv_stereo_chessboard", "left*.jpg", "checkerboard:9x6:0.025",
                   "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=12_Ny=10_fov_x_deg=80"),
    CalibrationSet("opencv_right", "opencv_stereo_chessboard", "right*.jpg", "checkerboard:9x6:0.025",
                   "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=12_Ny=10_fov_x_deg=80"),
    # 1920x1020 behind a lens of about 116 deg across (the README's equidistant fit: 946 px focal length, 960 px to
    # the edge); 125 deg with 10x7 knots (4/7 = 0.57 of the width down, the image needs 0.53). 8 views of a small
    # 42-corner board give 672 measurements: 16x10 knots (320 spline values) would be mostly unconstrained.
    CalibrationSet("vlp16_wide", "vlp16_camera_checkerboard", "vlp*.jpg", "checkerboard:7x6:0.05",
                   "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=10_Ny=7_fov_x_deg=125"),
)
PLAIN = ["--skip-calobject-warp-solve", "--skip-outlier-rejection", "--skip-regularization"]
MRCAL_SOLVES = {"a_opencv5_plain": ("LENSMODEL_OPENCV5", PLAIN), "b_opencv5_flex_outliers": ("LENSMODEL_OPENCV5", []),
                "c_splined": (None, [])}
"""mrcal's solves: the lens model (None: the set's ``spline``) and the options beyond the board and the corners."""

MRCAL_FIGURES = r"""
import json, sys
import numpy as np
import mrcal

job = json.load(sys.stdin)
pixels = np.array(job["pixels"], float)
rays = np.array(job["rays"], float)
inverted = np.array(job["inverted"], bool)
figures = {}
for name, path in job["models"].items():
    model = mrcal.cameramodel(path)
    inputs = model.optimization_inputs()
    lensmodel, intrinsics = model.intrinsics()
    residuals = mrcal.residuals_chessboard(inputs)
    weights = inputs["observations_board"][..., 2]
    warp = inputs.get("calobject_warp")
    directions = mrcal.unproject(pixels, lensmodel, intrinsics, normalize=True)
    unprojected = np.linalg.norm(directions, axis=1) > 0
    sigma = mrcal.projection_uncertainty(directions, model, atinfinity=True, what="worstdirection-stdev")
    difference = np.linalg.norm(mrcal.project(rays[inverted], lensmodel, intrinsics) - pixels[inverted], axis=1)
    figures[name] = {
        "lensmodel": lensmodel,
        "rms_px": float(np.sqrt(np.mean(np.sum(residuals**2, axis=1)))),
        "corners_used": int(np.count_nonzero(weights > 0)),
        "corners_rejected": int(np.count_nonzero(weights <= 0)) - job["missing"],
        "calobject_warp_mm": None if warp is None else (1000 * np.asarray(warp)).tolist(),
        "projection_sigma_px": {"centre": float(sigma[job["centre"]]), "worst": float(sigma[unprojected].max())},
        "grid_cells_not_inverted": int(np.count_nonzero(~unprojected)),
        "max_projection_difference_px": float(difference.max()),
        "cells": {"sigma_px": sigma.tolist(), "inverted": unprojected.tolist()},
    }
print(json.dumps(figures))
"""
"""Run by Debian's Python: reads {models: {solve: path}, pixels, rays, inverted, centre, missing} on stdin and prints
each solve's figures (module docstring)."""


def mrcal_version() -> str | None:
    """Debian's mrcal package version, or None when its Python or its calibration command is missing."""
    if shutil.which("mrcal-calibrate-cameras") is None or not Path(MRCAL_PYTHON).exists():
        return None
    if subprocess.run([MRCAL_PYTHON, "-c", "import mrcal"], capture_output=True).returncode != 0:
        return None
    if shutil.which("dpkg-query") is None:
        return "unknown"
    query = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "python3-mrcal"], capture_output=True, text=True)
    return query.stdout.strip() or "unknown"


def uncertainty_grid(camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The studio's uncertainty grid: cell-centre pixels (N, 2), ``camera``'s rays there (N, 3), and whether
    ``camera`` projects each ray back onto its pixel (N,)."""
    pixels = grid_pixels(camera.width, camera.height, UNCERTAINTY_GRID)
    rays = camera.rays_where_inverting(pixels)
    rays[np.isnan(rays[:, 0])] = (0.0, 0.0, 1.0)  # a cell where a spline folds is not inverted; mrcal gets the axis
    return pixels, rays, np.linalg.norm(camera.project(rays) - pixels, axis=1) < ROUND_TRIP_PX


def sigma_figures(projection_uncertainty: dict, inverted: np.ndarray) -> dict:
    """The sigmas (px) the result reports, and the worst over the grid cells where its model inverts."""
    return {"centre": projection_uncertainty["centre_px"], "worst": projection_uncertainty["max_px"],
            "worst_where_inverted": float(np.ravel(projection_uncertainty["sigma_px"])[inverted].max())}


def ours(views: list[View], board: BoardSpec, size: tuple[int, int], spline: SplineGrid):
    """The studio's solve as reported, the same with the board flat, and the splined model's solve on ``spline``;
    returns (result, figures, cells): ``cells`` per mrcal solve it is compared with, the per-cell sigma and whether
    the model inverts there."""
    settings = IntrinsicsSettings(estimate_k3=True, cross_validate=False)
    result = calibrate_intrinsics(views, board, size, settings)
    flat = calibrate_intrinsics(views, board, size, replace(settings, board_flex=False, jackknife=False))
    splined = calibrate_intrinsics(views, board, size, replace(settings, model="splined-stereographic",
                                                               spline_knots=(spline.nx, spline.ny),
                                                               spline_fov_x_deg=spline.fov_x_deg))
    inverted = uncertainty_grid(result.camera)[2]
    splined_inverted = uncertainty_grid(splined.camera)[2]
    figures = {"rms_px": result.rms_px, "views": len(views), "corners": result.corners["chosen"],
               "corners_rejected": result.summary()["rejected_corners"],
               "calobject_warp_mm": result.board_flex["warp_mm"], "calobject_warp_std_mm": result.board_flex["std_mm"],
               "projection_sigma_px": sigma_figures(result.projection_uncertainty, inverted),
               "projection_sigma_max_covered_px": result.projection_uncertainty["max_covered_px"],
               "jackknife_projection_max_px": result.jackknife["projection_max_px"],
               "flat": {"rms_px": flat.rms_px,
                        "projection_sigma_px": sigma_figures(flat.projection_uncertainty, inverted)},
               "splined": {"lensmodel": splined.splined["lensmodel"], "rms_px": splined.rms_px,
                           "corners": splined.corners["chosen"],
                           "corners_rejected": splined.summary()["rejected_corners"],
                           "calobject_warp_mm": splined.board_flex["warp_mm"],
                           "projection_sigma_px": sigma_figures(splined.projection_uncertainty, splined_inverted),
                           "unconstrained_knots": splined.splined["unconstrained_knots"],
                           "knots_under_image": splined.splined["knots_under_image"],
                           "opencv_fit_max_residual_px": splined.splined["opencv"]["max_residual_px"],
                           "verdict": splined.verdict.level, "seconds": splined.seconds},
               "grid_cells_not_inverted": int(np.count_nonzero(~inverted)),
               "camera": result.camera.to_dict(), "seconds": result.seconds}
    cells = {"a_opencv5_plain": (flat.projection_uncertainty, inverted),
             "b_opencv5_flex_outliers": (result.projection_uncertainty, inverted),
             "c_splined": (splined.projection_uncertainty, splined_inverted)}
    return result, figures, {solve: {"sigma_px": np.ravel(unc["sigma_px"]), "inverted": mask,
                                     "reached": np.ravel(unc["covered"])} for solve, (unc, mask) in cells.items()}


def write_corners_cache(path: Path, views: list[View], board: BoardSpec, corner_set: str) -> int:
    """mrcal's corners cache of ``views``' ``corner_set`` corners, images named under ``path``'s folder; returns how
    many of the board's corners were missing (written as ``- - -`` rows)."""
    lines, missing = ["# filename x y level"], 0
    for view in views:
        full = np.full((board.n_corners, 2), np.nan)
        full[view.detection.ids] = view.detection.refined.get(corner_set, view.detection.corners_px)
        image = path.parent / view.name
        lines += [f"{image} - - -" if np.isnan(x) else f"{image} {x:.6f} {y:.6f} 0" for x, y in full]
        missing += int(np.isnan(full[:, 0]).sum())
    path.write_text("\n".join(lines) + "\n")
    return missing


def run_mrcal(folder: Path, calibration_set: CalibrationSet, board: BoardSpec, camera: CameraIntrinsics,
              solve: str, lensmodel: str, options: list[str]) -> dict:
    """One ``mrcal-calibrate-cameras`` run on ``folder``'s corners cache; returns the model's path and the seconds,
    or the error's last line."""
    out = folder / solve
    out.mkdir()
    cols, rows = board.corner_grid
    command = ["mrcal-calibrate-cameras", "--corners-cache", str(folder / "corners.vnl"), "--lensmodel", lensmodel,
               "--focal", f"{camera.K[0, 0]:.0f}", "--object-spacing", str(board.square_m),
               "--object-width-n", str(cols), "--object-height-n", str(rows),
               "--imagersize", str(camera.width), str(camera.height), "--outdir", str(out), *options,
               str(folder / calibration_set.pattern)]
    started = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if run.returncode != 0:
        return {"error": (run.stderr.strip().splitlines() or ["no message"])[-1]}
    return {"model": str(out / "camera-0.cameramodel"), "seconds": seconds}


def mrcal_figures(models: dict[str, str], camera: CameraIntrinsics, missing: int) -> dict:
    """Each mrcal model's figures (:data:`MRCAL_FIGURES`), over the studio's uncertainty grid."""
    cols, rows = UNCERTAINTY_GRID
    pixels, rays, inverted = uncertainty_grid(camera)
    job = {"models": models, "pixels": pixels.tolist(), "rays": rays.tolist(), "inverted": inverted.tolist(),
           "centre": (rows // 2) * cols + cols // 2, "missing": missing}
    run = subprocess.run([MRCAL_PYTHON, "-c", MRCAL_FIGURES], input=json.dumps(job), capture_output=True, text=True,
                         check=True)
    return json.loads(run.stdout)


def ratios(our_figures: dict, mrcal: dict, our_cells: dict, their_cells: dict) -> dict:
    """ours / mrcal's for RMS and the projection sigma (centre, worst), like for like: our flat-board solve against
    mrcal's plain OPENCV5 (a), our result (flex solved) against mrcal's default (b), our splined solve against
    mrcal's (c). ``sigma_worst`` takes each side's worst over the grid cells where its own model inverts;
    ``sigma_worst_where_both`` over the cells where both do (a polynomial fitted to a fisheye folds at different
    cells in each tool), ``sigma_worst_where_reached`` over those of them the views' boards reach (the verdict's
    figure; near a fold the sigma grows without bound, so two fits that fold apart differ most there)."""
    result = {}
    like_for_like = {"a_opencv5_plain": our_figures["flat"], "b_opencv5_flex_outliers": our_figures,
                     "c_splined": our_figures["splined"]}
    for solve, like in like_for_like.items():
        theirs = mrcal[solve]
        if "rms_px" not in theirs:
            continue
        result[solve] = {"rms_px": like["rms_px"] / theirs["rms_px"],
                         "sigma_centre": (like["projection_sigma_px"]["centre"]
                                          / theirs["projection_sigma_px"]["centre"]),
                         "sigma_worst": (like["projection_sigma_px"]["worst_where_inverted"]
                                         / theirs["projection_sigma_px"]["worst"])}
        ours_cells, mrcal_cells = our_cells[solve], their_cells[solve]
        both = ours_cells["inverted"] & np.asarray(mrcal_cells["inverted"], bool)
        reached = both & ours_cells["reached"]
        for name, cells in (("sigma_worst_where_both", both), ("sigma_worst_where_reached", reached)):
            if cells.any():
                result[solve][name] = float(ours_cells["sigma_px"][cells].max()
                                            / np.asarray(mrcal_cells["sigma_px"])[cells].max())
    return result


def evaluate(calibration_set: CalibrationSet, version: str | None) -> dict:
    """The studio's figures on one set, and mrcal's beside them when ``version`` says it is installed."""
    board = BoardSpec.parse(calibration_set.board)
    paths = sorted((DATA / calibration_set.folder).glob(calibration_set.pattern))
    log(f"{calibration_set.name}: detecting the board in {len(paths)} images ...")
    detections = [(p.name, detect_board(cv2.imread(str(p)), board)) for p in paths]
    views = [View(name, d) for name, d in detections if d is not None]
    size = views[0].detection.image_size
    log(f"{calibration_set.name}: the studio's solve on {len(views)} views ...")
    result, our_figures, our_cells = ours(views, board, size, SplineGrid.from_mrcal_name(calibration_set.spline))
    if version is None:
        return {"ours": our_figures}
    with tempfile.TemporaryDirectory(prefix="intrinsics_vs_mrcal_") as tmp:
        folder = Path(tmp)
        missing = write_corners_cache(folder / "corners.vnl", views, board, result.corners["chosen"])
        runs = {}
        for solve, (lensmodel, options) in MRCAL_SOLVES.items():
            log(f"{calibration_set.name}: mrcal {solve} ...")
            runs[solve] = run_mrcal(folder, calibration_set, board, result.camera, solve,
                                    lensmodel or calibration_set.spline, options)
        models = {solve: run["model"] for solve, run in runs.items() if "model" in run}
        figures = mrcal_figures(models, result.camera, missing) if models else {}
    their_cells = {solve: figures[solve].pop("cells") for solve in figures}
    mrcal = {solve: {**figures.get(solve, {}), **{k: v for k, v in run.items() if k != "model"}}
             for solve, run in runs.items()}
    return {"ours": our_figures, "mrcal": mrcal,
            "ratios_ours_over_mrcal": ratios(our_figures, mrcal, our_cells, their_cells)}


def main():
    started = time.perf_counter()
    version = mrcal_version()
    log(f"mrcal: {version or 'not installed'}")
    results = {s.name: evaluate(s, version) for s in SETS}
    mrcal = {"mrcal_version": version} if version else {"mrcal": "not installed"}
    print(json.dumps({**mrcal, "sets": results, "seconds": time.perf_counter() - started}, indent=1))


if __name__ == "__main__":
    main()
