"""The report's plots, drawn with matplotlib and embedded as ``data:`` URIs of SVG (nothing is fetched).

Each function takes what :mod:`backend.reports.gather` read and returns one image. Figures are made
with :class:`matplotlib.figure.Figure` directly (no pyplot state), so reports can be drawn from any thread.
"""

from __future__ import annotations

import base64
import io
import math

import matplotlib as mpl
import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import FancyArrowPatch, Patch

from backend.calib.rig.graph import RigTree
from backend.core.verdict import PROJECTION_TOLERANCE_PX
from backend.reports.gather import CameraReport, EdgeReport

USED, OUTLIER, UNUSED = "#3b6ea8", "#c0392b", "#a0a0a0"
AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
"""x, y, z axes of a drawn frame."""
CHI2_MAX = 3.0
"""Upper end of the residual colour scale (normalised chi^2, per degree of freedom)."""
RESIDUAL_COLOURS = mpl.colormaps["RdYlGn_r"]
STYLE = {"font.size": 8, "axes.titlesize": 9, "axes.labelsize": 8, "svg.fonttype": "path", "figure.dpi": 100}


def to_data_uri(figure: Figure) -> str:
    """The figure as an SVG ``data:`` URI (self-contained: fonts drawn as paths)."""
    buffer = io.BytesIO()
    with mpl.rc_context(STYLE):
        figure.savefig(buffer, format="svg", bbox_inches="tight")
    return "data:image/svg+xml;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _figure(width_in: float, height_in: float) -> Figure:
    with mpl.rc_context(STYLE):
        return Figure(figsize=(width_in, height_in), layout="constrained")


def _nice_factor(value: float) -> float:
    """The 1-2-5 step at or below ``value`` (for arrow and ellipsoid scales), at least 1."""
    if not math.isfinite(value) or value <= 1:
        return 1.0
    exponent = math.floor(math.log10(value))
    mantissa = max(m for m in (1, 2, 5) if m * 10**exponent <= value)
    return float(mantissa * 10**exponent)


def _image_axes(ax, size: tuple[int, int], title: str) -> None:
    """Axes over an image of ``size`` (width, height) px, rows down as in the image."""
    ax.set_xlim(0, size[0])
    ax.set_ylim(size[1], 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(title)


def view_rms_bars(camera: CameraReport) -> str:
    """Per-view RMS reprojection error (px): used views, outliers (red) and views left out (grey)."""
    with mpl.rc_context(STYLE):
        figure = _figure(7.0, 2.4)
        ax = figure.add_subplot()
        colours = [OUTLIER if v.outlier else USED if v.used else UNUSED for v in camera.views]
        ax.bar(range(len(camera.views)), [v.rms_px for v in camera.views], color=colours)
        ax.axhline(camera.record["rms_px"], color="#333333", lw=0.8, ls="--")
        ax.set_xticks(range(len(camera.views)), [v.name for v in camera.views], rotation=60, ha="right")
        ax.set_ylabel("RMS (px)")
        ax.set_title(f"{camera.sensor}: reprojection RMS per view (dashed: all views, "
                     f"{camera.record['rms_px']:.3f} px)")
        ax.legend(handles=[Patch(color=USED, label="used"), Patch(color=OUTLIER, label="outlier"),
                           Patch(color=UNUSED, label="not used")], loc="upper right", fontsize=7)
        return to_data_uri(figure)


def _residual_arrays(camera: CameraReport) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners (N, 2) px, residuals (N, 2) px and view index (N,) of the used views that have residuals."""
    kept = [(i, v) for i, v in enumerate(camera.views) if v.used and v.residuals_px is not None]
    if not kept:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int)
    corners = np.vstack([v.corners_px for _, v in kept])
    residuals = np.vstack([v.residuals_px for _, v in kept])
    views = np.concatenate([np.full(len(v.corners_px), i) for i, v in kept])
    return corners, residuals, views


def residual_vectors(camera: CameraReport) -> str:
    """Every used corner's residual (detected minus projected) as an arrow across the image, scaled up to be seen,
    coloured by its length (px); beside it the residuals themselves, one colour per view (as Kalibr shows them)."""
    corners, residuals, views = _residual_arrays(camera)
    size = camera.image_size
    with mpl.rc_context(STYLE):
        figure = _figure(7.0, 3.0)
        left, right = figure.subplots(1, 2, gridspec_kw={"width_ratios": [1.9, 1]})
        length = np.linalg.norm(residuals, axis=1)
        p95 = float(np.percentile(length, 95)) if len(length) else 0.0
        scale = _nice_factor(0.04 * size[0] / p95) if p95 > 0 else 1.0
        _image_axes(left, size, f"residual vectors x{scale:g}")
        if len(corners):
            arrows = left.quiver(corners[:, 0], corners[:, 1], residuals[:, 0] * scale, residuals[:, 1] * scale,
                                 length, cmap="viridis", angles="xy", scale_units="xy", scale=1, width=0.003)
            figure.colorbar(arrows, ax=left, label="|residual| (px)", shrink=0.8)
            right.scatter(residuals[:, 0], residuals[:, 1], c=views, cmap="tab20", s=3, lw=0)
            rms = float(np.sqrt(np.mean(length**2)))
            right.add_patch(mpl.patches.Circle((0, 0), rms, fill=False, color="#333333", lw=0.8, ls="--"))
            lim = 1.15 * float(length.max())
            right.set_xlim(-lim, lim)
            right.set_ylim(lim, -lim)
        right.set_aspect("equal")
        right.set_xlabel("du (px)")
        right.set_ylabel("dv (px)")
        right.set_title("residuals by view (dashed: RMS)")
        return to_data_uri(figure)


def coverage_map(camera: CameraReport) -> str:
    """How many used corners fell in each cell of the image, with every corner drawn as a dot."""
    size = camera.image_size
    corners = [v.corners_px for v in camera.views if v.used]
    corners = np.vstack(corners) if corners else np.zeros((0, 2))
    nx = 16
    ny = max(1, round(nx * size[1] / size[0]))
    counts, _, _ = np.histogram2d(corners[:, 0], corners[:, 1], bins=(nx, ny), range=((0, size[0]), (0, size[1])))
    empty = int(np.count_nonzero(counts == 0))
    with mpl.rc_context(STYLE):
        figure = _figure(4.6, 3.0)
        ax = figure.add_subplot()
        cells = ax.imshow(counts.T, extent=(0, size[0], size[1], 0), cmap="Greens", interpolation="nearest",
                          vmin=0)
        ax.scatter(corners[:, 0], corners[:, 1], s=1, c="#222222", lw=0)
        _image_axes(ax, size, f"corner coverage ({len(corners)} corners; {empty} of {nx * ny} cells empty)")
        figure.colorbar(cells, ax=ax, label="corners per cell", shrink=0.8)
        return to_data_uri(figure)


def projection_maps(camera: CameraReport) -> str | None:
    """mrcal's diagnostics across the image: the projection 1-sigma (px, contour at the tolerance) and, when the
    cross-validation was made, the difference between the two halves' projections (px). None without either."""
    record = camera.record
    panels = []
    sigma = record.get("projection_uncertainty", {}).get("sigma_px")
    if sigma is not None:
        panels.append((np.asarray(sigma, dtype=float), "projection sigma (px)", PROJECTION_TOLERANCE_PX))
    difference = record.get("cross_validation", {}).get("difference_px")
    if difference is not None:
        panels.append((np.asarray(difference, dtype=float), "cross-validation: halves differ by (px)", None))
    if not panels:
        return None
    size = camera.image_size
    with mpl.rc_context(STYLE):
        figure = _figure(3.5 * len(panels), 2.4)
        for ax, (grid, title, contour) in zip(np.atleast_1d(figure.subplots(1, len(panels))), panels, strict=True):
            image = ax.imshow(grid, extent=(0, size[0], size[1], 0), cmap="magma", interpolation="bilinear")
            if contour is not None and grid.min() < contour < grid.max():
                u = (np.arange(grid.shape[1]) + 0.5) * size[0] / grid.shape[1]
                v = (np.arange(grid.shape[0]) + 0.5) * size[1] / grid.shape[0]
                lines = ax.contour(u, v, grid, levels=[contour], colors="white", linewidths=0.8)
                ax.clabel(lines, fmt=f"{contour:g} px", fontsize=6)
            _image_axes(ax, size, title)
            figure.colorbar(image, ax=ax, shrink=0.8)
        return to_data_uri(figure)


def c2c_histogram(edge: EdgeReport) -> str:
    """Histogram of a LiDAR-LiDAR edge's cloud-to-cloud distances (mm) with their mean, median and 95th percentile."""
    d_mm = edge.c2c_m * 1e3
    with mpl.rc_context(STYLE):
        figure = _figure(5.0, 2.4)
        ax = figure.add_subplot()
        ax.hist(d_mm, bins=60, color=USED)
        for value, label, style in ((d_mm.mean(), "mean", "-"), (np.median(d_mm), "median", "--"),
                                    (np.percentile(d_mm, 95), "p95", ":")):
            ax.axvline(value, color="#333333", ls=style, lw=0.9, label=f"{label} {value:.1f} mm")
        ax.set_xlabel("distance to the target cloud (mm)")
        ax.set_ylabel("points")
        ax.set_title(f"{edge.result.child} -> {edge.result.parent}: cloud-to-cloud distance ({len(d_mm)} points)")
        ax.legend(fontsize=7)
        return to_data_uri(figure)


RMS_SUFFIXES = ("rms_m", "rmse_m", "rms_px")
"""Keys of a per-unit diagnostics entry that hold an RMS residual (m or px)."""


def unit_residual_bars(edge: EdgeReport) -> str | None:
    """Bars of the RMS residuals of each unit (pose, scene, set) a transform was solved from, read from the first
    list of two or more entries in its diagnostics that hold any (keys ending in :data:`RMS_SUFFIXES`); None
    without one."""
    for key, entries in edge.result.diagnostics.items():
        if not (isinstance(entries, list) and len(entries) > 1 and all(isinstance(e, dict) for e in entries)):
            continue
        columns = [c for c in entries[0] if c.endswith(RMS_SUFFIXES) and all(
            isinstance(e.get(c), int | float) for e in entries)]
        if not columns:
            continue
        labels = [str(e.get("name", k)) for k, e in enumerate(entries)]
        with mpl.rc_context(STYLE):
            figure = _figure(7.0, 2.4)
            ax = figure.add_subplot()
            width = 0.8 / len(columns)
            for j, column in enumerate(columns):
                in_mm = column.endswith("_m")
                values = [e[column] * (1e3 if in_mm else 1.0) for e in entries]
                ax.bar(np.arange(len(entries)) + (j - (len(columns) - 1) / 2) * width, values, width,
                       label=f"{column} ({'mm' if in_mm else 'px'})")
            ax.set_xticks(range(len(entries)), labels, rotation=30 if len(labels) > 4 else 0, ha="right",
                          fontsize=6)
            units = sorted({"mm" if c.endswith("_m") else "px" for c in columns})
            ax.set_ylabel(f"RMS ({' or '.join(units)})")
            ax.set_title(f"{edge.result.parent} -> {edge.result.child}: residual RMS per entry of '{key}'")
            ax.legend(fontsize=7)
            return to_data_uri(figure)
    return None


def _residual_colour(chi2: float) -> tuple:
    return RESIDUAL_COLOURS(min(chi2, CHI2_MAX) / CHI2_MAX) if math.isfinite(chi2) else UNUSED


def observation_graph(tree: RigTree) -> str:
    """Which frames were calibrated against which: the root in the middle, every other frame on a circle,
    mounting priors dashed grey, each accepted edge coloured by its normalised chi^2 in the fused tree (flagged
    edges thick, marked with '!'); several edges between one pair are bent apart."""
    names = sorted({name for r in tree.edges for name in (r.edge.parent, r.edge.child)} | set(tree.frames)
                   - {tree.root})
    angles = np.linspace(0, 2 * np.pi, len(names), endpoint=False) + np.pi / 2
    position = {tree.root: (0.0, 0.0)} | {n: (math.cos(a), math.sin(a)) for n, a in zip(names, angles, strict=True)}
    with mpl.rc_context(STYLE):
        figure = _figure(6.0, 5.0)
        ax = figure.add_subplot()
        seen: dict[frozenset, int] = {}
        for residual in tree.edges:
            edge = residual.edge
            pair = frozenset((edge.parent, edge.child))
            bend = 0.25 * seen.get(pair, 0) * (-1) ** seen.get(pair, 0)
            seen[pair] = seen.get(pair, 0) + 1
            prior = edge.kind == "prior"
            colour = "#b0b0b0" if prior else _residual_colour(residual.chi2)
            ax.add_patch(FancyArrowPatch(position[edge.parent], position[edge.child], arrowstyle="-|>",
                                         mutation_scale=9, connectionstyle=f"arc3,rad={bend}", color=colour,
                                         lw=0.8 if prior else (3.0 if residual.flagged else 1.8),
                                         ls="--" if prior else "-", shrinkA=14, shrinkB=14))
            if not prior:
                (x0, y0), (x1, y1) = position[edge.parent], position[edge.child]
                mx, my = (x0 + x1) / 2 - bend * (y1 - y0) / 2, (y0 + y1) / 2 + bend * (x1 - x0) / 2
                ax.text(mx, my, f"{edge.kind}\nchi2 {residual.chi2:.2f}{' !' if residual.flagged else ''}",
                        fontsize=6, ha="center", va="center", color="#222222",
                        bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": colour, "lw": 0.6})
        for name, (x, y) in position.items():
            ax.text(x, y, name, ha="center", va="center", fontsize=7, zorder=3,
                    bbox={"boxstyle": "round,pad=0.3", "fc": "#eef2f7" if name != tree.root else "#fff4d6",
                          "ec": "#555555", "lw": 0.6})
        ax.set_xlim(-1.35, 1.35)
        ax.set_ylim(-1.25, 1.25)
        ax.set_aspect("equal")
        ax.axis("off")
        bar = mpl.cm.ScalarMappable(Normalize(0, CHI2_MAX), RESIDUAL_COLOURS)
        figure.colorbar(bar, ax=ax, shrink=0.6, label="edge residual: normalised chi2 (dashed grey: mounting prior)")
        return to_data_uri(figure)


def _ellipsoid_scale(tree: RigTree, extent_m: float) -> float:
    """A 1-2-5 factor that makes the largest frame 1-sigma ellipsoid about 4 % of the rig's extent."""
    largest = max((math.sqrt(max(np.linalg.eigvalsh(f.covariance_root_translation).max(), 0.0))
                   for f in tree.frames.values() if np.isfinite(f.covariance_root_translation).all()), default=0.0)
    return _nice_factor(0.04 * extent_m / largest) if largest > 0 else 1.0


def rig_drawing(tree: RigTree) -> tuple[str, float]:
    """The fused rig in the root frame: each frame's axes (x red, y green, z blue) and 1-sigma position ellipsoid
    scaled up, the tree's parent links (grey) and the accepted edges coloured by residual; in 3D and from above.
    Returns the image and the ellipsoid scale."""
    poses = {tree.root: np.eye(4)} | {name: f.T_root_frame for name, f in tree.frames.items()}
    origins = np.array([T[:3, 3] for T in poses.values()])
    extent_m = max(float(np.ptp(origins, axis=0).max()), 0.2)
    axis_m = 0.08 * extent_m
    scale = _ellipsoid_scale(tree, extent_m)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 16), np.linspace(0, np.pi, 9))
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
    circle = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 33)), np.sin(np.linspace(0, 2 * np.pi, 33))])
    with mpl.rc_context(STYLE):
        figure = _figure(8.0, 4.4)
        grid = figure.add_gridspec(1, 2, width_ratios=[1.5, 1])
        ax3d = figure.add_subplot(grid[0], projection="3d")
        top = figure.add_subplot(grid[1])
        for frame in tree.frames.values():
            if frame.parent in poses:
                line = np.array([poses[frame.parent][:3, 3], frame.T_root_frame[:3, 3]])
                ax3d.plot(*line.T, color="#b0b0b0", lw=0.8, ls="--")
                top.plot(line[:, 1], line[:, 0], color="#b0b0b0", lw=0.8, ls="--")
            cov = frame.covariance_root_translation
            if np.isfinite(cov).all():
                values, vectors = np.linalg.eigh(cov)
                shell = sphere @ (vectors * np.sqrt(np.clip(values, 0, None)) * scale).T + frame.T_root_frame[:3, 3]
                ax3d.plot_wireframe(shell[..., 0], shell[..., 1], shell[..., 2], color="#7f5fb0", lw=0.3)
                values, vectors = np.linalg.eigh(cov[np.ix_([1, 0], [1, 0])])  # (y, x) as the top view draws
                ring = circle @ (vectors * np.sqrt(np.clip(values, 0, None)) * scale).T
                top.plot(ring[:, 0] + frame.T_root_frame[1, 3], ring[:, 1] + frame.T_root_frame[0, 3],
                         color="#7f5fb0", lw=0.6)
        for residual in tree.edges:
            edge = residual.edge
            if edge.kind != "prior" and edge.parent in poses and edge.child in poses:
                line = np.array([poses[edge.parent][:3, 3], poses[edge.child][:3, 3]])
                colour = _residual_colour(residual.chi2)
                ax3d.plot(*line.T, color=colour, lw=2.0)
                top.plot(line[:, 1], line[:, 0], color=colour, lw=2.0)
        for name, T in poses.items():
            for k, colour in enumerate(AXIS_COLOURS):
                tip = T[:3, 3] + axis_m * T[:3, k]
                ax3d.plot(*np.array([T[:3, 3], tip]).T, color=colour, lw=1.2)
                top.plot([T[1, 3], tip[1]], [T[0, 3], tip[0]], color=colour, lw=1.2)
            ax3d.text(*T[:3, 3], f" {name}", fontsize=6)
            top.annotate(name, (T[1, 3], T[0, 3]), xytext=(3, 3), textcoords="offset points", fontsize=6)
        centre = (origins.max(axis=0) + origins.min(axis=0)) / 2
        half = 0.6 * extent_m
        ax3d.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half),
                 zlim=(centre[2] - half, centre[2] + half), xlabel="x (m)", ylabel="y (m)", zlabel="z (m)")
        ax3d.set_box_aspect((1, 1, 1))
        ax3d.set_title(f"{tree.root} frame, 3D")
        top.set_aspect("equal")
        top.invert_xaxis()  # y to the left, as seen from above with x forward (up the page)
        top.set_xlabel("y (m)")
        top.set_ylabel("x (m)")
        top.set_title(f"from above, x forward (sigma ellipsoids x{scale:g})")
        top.grid(True, lw=0.3)
        return to_data_uri(figure), scale
