"""Solving mrcal's splined lens model (:mod:`backend.core.splined`) from board views, as mrcal does.

The knots and the field of view are chosen from an OpenCV solve of the same views (:func:`choose_grid`) unless the
user names them: the field across the image plus a margin, square knots that cover the image's height, and as many
knots as the corners measure :data:`MEASUREMENTS_PER_VALUE` times over. The spline starts as that OpenCV lens
(:func:`start_camera`: the control points fitted to its projection over the image) and is then solved with the
board's flex and every view's pose (:func:`~backend.calib.intrinsics.flex.refine_with_flex`), with ``fx, fy, cx, cy``
held as mrcal holds them (the spline takes up what they would) and mrcal's regularization (:func:`regularization`):
each control point pulled toward zero, gently along its knot's radius and ten times harder across it, so knots no
corner reaches stay smooth instead of free. The result says which knots under the image no corner reaches
(:func:`knots_report`), where the model is extrapolated.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from backend.core.camera import CameraIntrinsics
from backend.core.camera_conversion import opencv_camera, pixel_grid
from backend.core.errors import InputError
from backend.core.splined import SplineGrid, stereographic

MEASUREMENTS_PER_VALUE = 5.0
"""The knots chosen (:func:`choose_grid`) leave at least this many corner measurements (x and y each count) per
spline value: the shared real sets' 12x10 and 10x7 knots of mrcal's fits have 5.9 and 4.8."""
MIN_MEASUREMENTS_PER_VALUE = 3.0
"""Fewer measurements per spline value than this is refused (:func:`check_measurements`): most knots would be held
by the regularization alone."""
KNOTS_ACROSS = (6, 16)
"""The fewest and most knots across that :func:`choose_grid` picks."""
FOV_MARGIN_DEG = 8.0
"""The field of view chosen is the image's across plus this, rounded up to 5 degrees (the shared sets: 80 and 125)."""
START_GRID = (64, 48)
"""Pixels (columns, rows) over the image where the start is fitted to the OpenCV lens (:func:`start_camera`)."""
ROUND_TRIP_PX = 0.01
"""An OpenCV lens inverts at a pixel when the pixel's ray projects back within this (px)."""
REGULARIZATION_SCALE = 0.005 / 2 / 0.2**2
"""mrcal's splined regularization weight: its penalties sum to 0.5 % of a solve whose corners are off by 1 px, with
control points of 0.2 (``mrcal.c``'s ``scale_regularization_splined``)."""
TANGENTIAL_WEIGHT = 10.0
"""mrcal weighs a control point across its knot's radius ten times its weight along it."""


def image_u(camera: CameraIntrinsics, columns: int = 64, rows: int = 48) -> np.ndarray:
    """Stereographic ``u`` (N, 2) of a grid of the image's pixels under ``camera``; where it does not invert (a
    polynomial fitted to a wide lens folds before the image's edge), the equidistant guess: the pixel's distance from
    the principal point over the focal length is its angle off the axis (a fisheye's, wider than a pinhole's)."""
    pixels = pixel_grid(camera, columns, rows)
    inverting, rays = _inverting_rays(camera, pixels)
    xy = (pixels[~inverting] - camera.K[:2, 2]) / np.diag(camera.K)[:2]
    angle = np.linalg.norm(xy, axis=1, keepdims=True)
    guessed = 2 * np.tan(np.minimum(angle, np.pi * 0.99) / 2) * xy / np.maximum(angle, 1e-12)
    return np.vstack([stereographic(rays)[0], guessed])


def _inverting_rays(camera: CameraIntrinsics, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of the ``pixels`` (N, 2) ``camera`` inverts (N,) (a ray in front that projects back within
    :data:`ROUND_TRIP_PX`), and those pixels' rays."""
    with np.errstate(all="ignore"):
        rays = camera.rays_where_inverting(pixels)
        ok = np.all(np.isfinite(rays), axis=1) & (rays[:, 2] > 0)
        ok[ok] = np.linalg.norm(camera.project(rays[ok]) - pixels[ok], axis=1) < ROUND_TRIP_PX
    return ok, rays[ok]


def choose_grid(camera: CameraIntrinsics, n_measurements: int, knots: tuple[int, int] | None = None,
                fov_x_deg: float | None = None) -> SplineGrid:
    """The splined model's grid for a lens like ``camera`` (an OpenCV solve of the views) measured by
    ``n_measurements`` corner coordinates: the given knots (across, down) and field of view, or, for each not given, the
    field of the image across plus :data:`FOV_MARGIN_DEG` and the most knots across (within :data:`KNOTS_ACROSS`)
    that keep :data:`MEASUREMENTS_PER_VALUE`. The knots down are as many as square knots need to cover the image's
    height."""
    u = image_u(camera)
    if fov_x_deg is None:
        half_across = float(np.max(np.abs(u[:, 0])))
        fov_x_deg = 5.0 * np.ceil((np.degrees(4 * np.arctan(half_across / 2)) + FOV_MARGIN_DEG) / 5.0)
        fov_x_deg = float(min(fov_x_deg, 355.0))
    height_share = float(np.max(np.abs(u[:, 1]))) / (2 * np.tan(np.radians(fov_x_deg) / 4))

    def grid(nx: int) -> SplineGrid:
        return SplineGrid(nx, 3 + max(1, int(np.ceil((nx - 3) * height_share - 1e-9))), fov_x_deg)

    if knots is not None:
        return SplineGrid(*knots, fov_x_deg)
    low, high = KNOTS_ACROSS
    fitting = [nx for nx in range(low, high + 1) if n_measurements >= MEASUREMENTS_PER_VALUE * grid(nx).n_control]
    return grid(max(fitting, default=low))


def check_measurements(grid: SplineGrid, n_views: int, corners_px: list[np.ndarray], size: tuple[int, int]) -> None:
    """Refuse a splined solve whose corners measure its spline values fewer than :data:`MIN_MEASUREMENTS_PER_VALUE`
    times over, saying how many views and measurements there are and where the image has no corners."""
    n_measurements = 2 * sum(len(c) for c in corners_px)
    if n_measurements >= MIN_MEASUREMENTS_PER_VALUE * grid.n_control:
        return
    empty = _empty_regions(corners_px, size)
    where = (f"the image has no corners at its {', '.join(empty)}" if empty else
             "every part of the image has some corners, so add views that fill it more")
    raise InputError(
        f"{n_views} views give {n_measurements} corner measurements for the {grid.nx}x{grid.ny} knots' "
        f"{grid.n_control} spline values; the splined model needs at least {MIN_MEASUREMENTS_PER_VALUE:g} "
        f"measurements per value ({int(MIN_MEASUREMENTS_PER_VALUE * grid.n_control)}): add views ({where}), or ask "
        "for fewer knots", "views")


REGIONS = (("top-left", "top", "top-right"), ("left", "centre", "right"), ("bottom-left", "bottom", "bottom-right"))
"""The image's ninths, named for a refusal (:func:`check_measurements`)."""


def _empty_regions(corners_px: list[np.ndarray], size: tuple[int, int]) -> list[str]:
    """The names of the image's ninths (:data:`REGIONS`) where no corner lies."""
    corners = np.vstack(corners_px)
    column = np.clip((3 * corners[:, 0] / size[0]).astype(int), 0, 2)
    row = np.clip((3 * corners[:, 1] / size[1]).astype(int), 0, 2)
    seen = np.zeros((3, 3), bool)
    seen[row, column] = True
    return [REGIONS[r][c] for r in range(3) for c in range(3) if not seen[r, c]]


def regularization(camera: CameraIntrinsics, n_measurements: int) -> tuple[np.ndarray, np.ndarray]:
    """mrcal's splined regularization of ``camera``'s control points: residuals (2 per knot: along its radius from
    the grid's centre, then ten times across it) and their Jacobian by ``[fx, fy, cx, cy, control...]``, weighted for
    a solve of ``n_measurements`` corner coordinates (:data:`REGULARIZATION_SCALE`)."""
    grid = camera.spline
    iy, ix = np.mgrid[0:grid.ny, 0:grid.nx]
    radial = np.stack([2 * ix - grid.nx + 1, 2 * iy - grid.ny + 1], axis=-1).reshape(-1, 2).astype(float)
    length = np.linalg.norm(radial, axis=1)
    centre = length == 0  # the centre knot of an odd grid: no radius, weighed alike both ways
    radial[centre], length[centre] = (1.0, 0.0), 1.0
    radial /= length[:, None]
    scale = np.sqrt(n_measurements * REGULARIZATION_SCALE / grid.n_control)
    across = np.where(centre, scale, TANGENTIAL_WEIGHT * scale)
    n = grid.nx * grid.ny
    J = np.zeros((2 * n, 4 + 2 * n))
    knot = np.arange(n)
    J[2 * knot, 4 + 2 * knot] = scale * radial[:, 0]
    J[2 * knot, 5 + 2 * knot] = scale * radial[:, 1]
    J[2 * knot + 1, 4 + 2 * knot] = across * radial[:, 1]
    J[2 * knot + 1, 5 + 2 * knot] = -across * radial[:, 0]
    return J[:, 4:] @ camera.dist, J


def start_camera(opencv: CameraIntrinsics, grid: SplineGrid, n_measurements: int) -> CameraIntrinsics:
    """The splined camera that best reproduces the OpenCV lens ``opencv`` over the image (a :data:`START_GRID` of
    pixels, those where it inverts), with ``opencv``'s ``K``: the control points by linear least squares, with
    :func:`regularization`'s rows."""
    pixels = pixel_grid(opencv, *START_GRID)
    inverting, rays = _inverting_rays(opencv, pixels)
    u, _ = stereographic(rays)
    zero = CameraIntrinsics("splined-stereographic", opencv.width, opencv.height, opencv.K,
                            np.zeros(grid.n_control), grid)
    f, c = zero.parameters[:2], zero.parameters[2:4]
    index, weights, _, _ = grid.support(u)
    A = np.zeros((2 * len(u), grid.n_control))
    rows = np.arange(len(u))[:, None]
    A[2 * rows, 2 * index] = f[0] * weights
    A[2 * rows + 1, 2 * index + 1] = f[1] * weights
    _, J_regularization = regularization(zero, n_measurements)
    b = (pixels[inverting] - c - f * u).ravel()
    control = np.linalg.lstsq(np.vstack([A, J_regularization[:, 4:]]),
                              np.concatenate([b, np.zeros(grid.n_control)]), rcond=None)[0]
    return zero.with_parameters(np.r_[zero.parameters[:4], control])


def knots_report(camera: CameraIntrinsics, corners_px: list[np.ndarray], n_measurements: int) -> dict[str, Any]:
    """The splined model as the result states it: mrcal's model name, the knots and field of view, the measurements
    per spline value, which knots under the image no corner reaches (``unconstrained_map``: a row per knot row, ``#``
    reached, ``.`` under the image but unreached, `` `` beyond the image), and the OpenCV lens fitted to it where the
    views' corners are (``opencv``, the residual between the two there and, ``max_residual_over_image_px``, over the
    image: what an export that cannot carry the spline gets)."""
    grid = camera.spline
    under_image = grid.touched_knots(image_u(camera))
    corners = np.vstack(corners_px)
    inverting, rays = _inverting_rays(camera, corners)
    reached = grid.touched_knots(stereographic(rays)[0])
    unreached = under_image & ~reached
    rows = ["".join("#" if r else ("." if i else " ") for r, i in zip(row_r, row_i, strict=True))
            for row_r, row_i in zip(reached, under_image, strict=True)]
    return {"lensmodel": grid.mrcal_name, "knots": [grid.nx, grid.ny], "fov_x_deg": grid.fov_x_deg,
            "spline_values": grid.n_control, "measurements": n_measurements,
            "measurements_per_value": round(n_measurements / grid.n_control, 2),
            "knots_under_image": int(under_image.sum()), "unconstrained_knots": int(unreached.sum()),
            "unconstrained_map": rows,
            "detail": (f"{int(unreached.sum())} of the {int(under_image.sum())} knots under the image have no corner "
                       "near them: there the model is held smooth by the regularization, not measured, and its sigma "
                       "understates the error"),
            "opencv": opencv_fit(camera, rays, corners[inverting], pixel_grid(camera, *START_GRID))}


def opencv_fit(camera: CameraIntrinsics, rays: np.ndarray, pixels: np.ndarray,
               image_pixels: np.ndarray) -> dict[str, Any]:
    """OpenCV's ``pinhole-radtan`` (k1, k2, p1, p2, k3) fitted to the splined ``camera`` where it is measured: at the
    views' corners, the ``rays`` (N, 3) it sees at their ``pixels`` (N, 2), with a turn of the camera's frame (the
    spline's own frame is set by the boards, and its constant terms take up a turn about the axis that OpenCV's model
    has no term for). Returns the camera, the turn (deg), the residual there (max and RMS, px) and, at the image's
    ``image_pixels`` (M, 2) where the fitted OpenCV lens inverts (beyond the corners its polynomial may fold), the
    largest residual and the share of ``image_pixels`` it covers."""
    start = np.r_[camera.parameters[:4], np.zeros(5), np.zeros(3)]

    def fitted(params: np.ndarray) -> tuple[CameraIntrinsics, Rotation]:
        return opencv_camera(camera, params), Rotation.from_rotvec(params[9:])

    def residual(params: np.ndarray) -> np.ndarray:
        opencv, turn = fitted(params)
        return (opencv.project(turn.apply(rays)) - pixels).ravel()

    opencv, turn = fitted(least_squares(residual, start, x_scale="jac", method="lm").x)
    at_corners = np.linalg.norm(opencv.project(turn.apply(rays)) - pixels, axis=1)
    inverting, opencv_rays = _inverting_rays(opencv, image_pixels)
    over_image = np.linalg.norm(camera.project(turn.inv().apply(opencv_rays)) - image_pixels[inverting], axis=1)
    return {"camera": opencv.to_dict(), "rotation_deg": float(np.degrees(turn.magnitude())),
            "max_residual_px": float(at_corners.max()), "rms_residual_px": float(np.sqrt(np.mean(at_corners**2))),
            "max_residual_over_image_px": float(over_image.max(initial=0.0)),
            "image_share_inverting": float(inverting.mean()),
            "note": "fitted at the views' corners, the camera's frame turned by rotation_deg (the spline's frame is "
                    "set by the boards); beyond the corners the two part ways"}
