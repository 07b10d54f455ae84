"""Plots of the rig and its transforms: the observation graph, the fused rig drawn with its sigma ellipsoids and
any transform's residual RMS per pose, scene or set."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import matplotlib as mpl
import numpy as np
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import FancyArrowPatch

from backend.plots.render import UNUSED, new_figure, nice_factor, styled

if TYPE_CHECKING:
    from backend.calib.rig.graph import RigTree

AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")
"""x, y, z axes of a drawn frame."""
CHI2_MAX = 3.0
"""Upper end of the residual colour scale (normalised chi^2, per degree of freedom)."""
RESIDUAL_COLOURS = mpl.colormaps["RdYlGn_r"]


RMS_SUFFIXES = ("rms_m", "rmse_m", "rms_px")
"""Keys of a per-unit diagnostics entry that hold an RMS residual (m or px)."""


def unit_residual_bars(diagnostics: dict[str, Any], parent: str, child: str) -> Figure | None:
    """Bars of the RMS residuals of each unit (pose, scene, set) the ``parent`` -> ``child`` transform was solved
    from, read from the first list of two or more entries in its ``diagnostics`` that hold any (keys ending in
    :data:`RMS_SUFFIXES`); None without one."""
    for key, entries in diagnostics.items():
        if not (isinstance(entries, list) and len(entries) > 1 and all(isinstance(e, dict) for e in entries)):
            continue
        columns = [c for c in entries[0] if c.endswith(RMS_SUFFIXES) and all(
            isinstance(e.get(c), int | float) for e in entries)]
        if not columns:
            continue
        labels = [str(e.get("name", k)) for k, e in enumerate(entries)]
        with styled():
            figure = new_figure(7.0, 2.4)
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
            ax.set_title(f"{parent} -> {child}: residual RMS per entry of '{key}'")
            ax.legend(fontsize=7)
            return figure
    return None


def _residual_colour(chi2: float) -> tuple:
    return RESIDUAL_COLOURS(min(chi2, CHI2_MAX) / CHI2_MAX) if math.isfinite(chi2) else UNUSED


def observation_graph(tree: RigTree) -> Figure:
    """Which frames were calibrated against which: the root in the middle, every other frame on a circle,
    mounting priors dashed grey, each accepted edge coloured by its normalised chi^2 in the fused tree (flagged
    edges thick, marked with '!'); several edges between one pair are bent apart."""
    names = sorted({name for r in tree.edges for name in (r.edge.parent, r.edge.child)} | set(tree.frames)
                   - {tree.root})
    angles = np.linspace(0, 2 * np.pi, len(names), endpoint=False) + np.pi / 2
    position = {tree.root: (0.0, 0.0)} | {n: (math.cos(a), math.sin(a)) for n, a in zip(names, angles, strict=True)}
    with styled():
        figure = new_figure(6.0, 5.0)
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
        return figure


def _ellipsoid_scale(tree: RigTree, extent_m: float) -> float:
    """A 1-2-5 factor that makes the largest frame 1-sigma ellipsoid about 4 % of the rig's extent."""
    largest = max((math.sqrt(max(np.linalg.eigvalsh(f.covariance_root_translation).max(), 0.0))
                   for f in tree.frames.values() if np.isfinite(f.covariance_root_translation).all()), default=0.0)
    return nice_factor(0.04 * extent_m / largest) if largest > 0 else 1.0


def rig_drawing(tree: RigTree) -> tuple[Figure, float]:
    """The fused rig in the root frame: each frame's axes (x red, y green, z blue) and 1-sigma position ellipsoid
    scaled up, the tree's parent links (grey) and the accepted edges coloured by residual; in 3D and from above.
    Returns the figure and the ellipsoid scale."""
    poses = {tree.root: np.eye(4)} | {name: f.T_root_frame for name, f in tree.frames.items()}
    origins = np.array([T[:3, 3] for T in poses.values()])
    extent_m = max(float(np.ptp(origins, axis=0).max()), 0.2)
    axis_m = 0.08 * extent_m
    scale = _ellipsoid_scale(tree, extent_m)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 16), np.linspace(0, np.pi, 9))
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
    circle = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 33)), np.sin(np.linspace(0, 2 * np.pi, 33))])
    with styled():
        figure = new_figure(8.0, 4.4)
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
        return figure, scale
