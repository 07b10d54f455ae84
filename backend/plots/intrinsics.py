"""Plots of a camera's intrinsics result: per-view RMS, residual vectors, corner coverage and mrcal's projection
maps across the image. The report and the studio's intrinsics step draw the same figures."""

from __future__ import annotations

from typing import Any

import matplotlib as mpl
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from backend.core.verdict import PROJECTION_TOLERANCE_PX
from backend.plots.render import OUTLIER, UNUSED, USED, empty_note, image_axes, new_figure, nice_factor, styled


def image_size(record: dict[str, Any]) -> tuple[int, int]:
    """An intrinsics record's image (width, height) in px."""
    return int(record["camera"]["width"]), int(record["camera"]["height"])


def view_rms_bars(sensor: str, record: dict[str, Any] | None, width_in: float = 7.0) -> Figure:
    """Per-view RMS reprojection error (px) of the record's ``views`` (``image``, ``rms_px``, ``used``,
    ``outlier``): used views, outliers (red) and views left out (grey), with the overall RMS dashed."""
    figure = new_figure(width_in, 2.4)
    if record is None or not record.get("views"):
        return empty_note(figure, "no result yet")
    views = record["views"]
    with styled():
        ax = figure.add_subplot()
        colours = [OUTLIER if v.get("outlier") else USED if v.get("used", True) else UNUSED for v in views]
        ax.bar(range(len(views)), [v["rms_px"] for v in views], color=colours)
        ax.axhline(record["rms_px"], color="#333333", lw=0.8, ls="--")
        ax.set_xticks(range(len(views)), [v["image"] for v in views], rotation=60, ha="right",
                      fontsize=7 if len(views) < 30 else 5)
        ax.set_ylabel("RMS (px)")
        ax.set_title(f"{sensor}: reprojection RMS per view (dashed: all views, {record['rms_px']:.3f} px)")
        ax.legend(handles=[Patch(color=USED, label="used"), Patch(color=OUTLIER, label="outlier"),
                           Patch(color=UNUSED, label="not used")], loc="best", fontsize=7)
    return figure


def residual_vectors(corners_px: np.ndarray, residuals_px: np.ndarray, view_index: np.ndarray,
                     size: tuple[int, int], rejected_px: np.ndarray | None = None) -> Figure:
    """Every used corner's residual (detected minus projected, (N, 2) px at ``corners_px``) as an arrow across the
    image of ``size`` (width, height) px, scaled up to be seen, coloured by its length, and the corners rejected as
    outliers (``rejected_px``, (M, 2) px) as red crosses; beside it the residuals themselves, one colour per view
    (``view_index``, (N,)), as Kalibr shows them."""
    with styled():
        figure = new_figure(7.0, 3.0)
        left, right = figure.subplots(1, 2, gridspec_kw={"width_ratios": [1.9, 1]})
        length = np.linalg.norm(residuals_px, axis=1)
        p95 = float(np.percentile(length, 95)) if len(length) else 0.0
        scale = nice_factor(0.04 * size[0] / p95) if p95 > 0 else 1.0
        image_axes(left, size, f"residual vectors x{scale:g}")
        if len(corners_px):
            arrows = left.quiver(corners_px[:, 0], corners_px[:, 1], residuals_px[:, 0] * scale,
                                 residuals_px[:, 1] * scale, length, cmap="viridis", angles="xy", scale_units="xy",
                                 scale=1, width=0.003)
            figure.colorbar(arrows, ax=left, label="|residual| (px)", shrink=0.8)
        if rejected_px is not None and len(rejected_px):
            left.scatter(rejected_px[:, 0], rejected_px[:, 1], marker="x", color="#e03131", s=14, lw=0.9,
                         label=f"rejected ({len(rejected_px)})")
            left.legend(loc="lower right", fontsize=6)
        if len(corners_px):
            right.scatter(residuals_px[:, 0], residuals_px[:, 1], c=view_index, cmap="tab20", s=3, lw=0)
            rms = float(np.sqrt(np.mean(length**2)))
            right.add_patch(mpl.patches.Circle((0, 0), rms, fill=False, color="#333333", lw=0.8, ls="--"))
            lim = 1.15 * float(length.max())
            right.set_xlim(-lim, lim)
            right.set_ylim(lim, -lim)
        right.set_aspect("equal")
        right.set_xlabel("du (px)")
        right.set_ylabel("dv (px)")
        right.set_title("residuals by view (dashed: RMS)")
    return figure


def coverage_map(corners_px: np.ndarray, size: tuple[int, int]) -> Figure:
    """How many used corners ((N, 2) px) fell in each cell of the image of ``size`` (width, height) px, with every
    corner drawn as a dot."""
    nx = 16
    ny = max(1, round(nx * size[1] / size[0]))
    counts, _, _ = np.histogram2d(corners_px[:, 0], corners_px[:, 1], bins=(nx, ny),
                                  range=((0, size[0]), (0, size[1])))
    empty = int(np.count_nonzero(counts == 0))
    with styled():
        figure = new_figure(4.6, 3.0)
        ax = figure.add_subplot()
        cells = ax.imshow(counts.T, extent=(0, size[0], size[1], 0), cmap="Greens", interpolation="nearest",
                          vmin=0)
        ax.scatter(corners_px[:, 0], corners_px[:, 1], s=1, c="#222222", lw=0)
        image_axes(ax, size, f"corner coverage ({len(corners_px)} corners; {empty} of {nx * ny} cells empty)")
        figure.colorbar(cells, ax=ax, label="corners per cell", shrink=0.8)
    return figure


def projection_maps(record: dict[str, Any]) -> Figure | None:
    """mrcal's diagnostics across the image: the projection 1-sigma (px, contour at the tolerance) and, when the
    cross-validation was made, the difference between the two halves' projections (px). None without either."""
    panels = []
    sigma = record.get("projection_uncertainty", {}).get("sigma_px")
    if sigma is not None:
        panels.append((np.asarray(sigma, dtype=float), "projection sigma (px)", PROJECTION_TOLERANCE_PX))
    difference = record.get("cross_validation", {}).get("difference_px")
    if difference is not None:
        panels.append((np.asarray(difference, dtype=float), "cross-validation: halves differ by (px)", None))
    if not panels:
        return None
    size = image_size(record)
    with styled():
        figure = new_figure(3.5 * len(panels), 2.4)
        for ax, (grid, title, contour) in zip(np.atleast_1d(figure.subplots(1, len(panels))), panels, strict=True):
            image = ax.imshow(grid, extent=(0, size[0], size[1], 0), cmap="magma", interpolation="bilinear")
            if contour is not None and grid.min() < contour < grid.max():
                u = (np.arange(grid.shape[1]) + 0.5) * size[0] / grid.shape[1]
                v = (np.arange(grid.shape[0]) + 0.5) * size[1] / grid.shape[0]
                lines = ax.contour(u, v, grid, levels=[contour], colors="white", linewidths=0.8)
                ax.clabel(lines, fmt=f"{contour:g} px", fontsize=6)
            image_axes(ax, size, title)
            figure.colorbar(image, ax=ax, shrink=0.8)
    return figure
