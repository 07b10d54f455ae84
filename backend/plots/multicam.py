"""Plots of a multi-camera solve: which cameras saw the board together (its observation graph), and every view's
reprojection RMS grouped by camera."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from backend.plots.render import OUTLIER, empty_note, new_figure, styled

NODE_COLOUR = "#2f6fdc"
ALONE_COLOUR = OUTLIER
"""A camera that shares no frame with any other: the solve cannot place it."""
CAMERA_COLOURS = ("#2f6fdc", "#28a06e", "#965ac8", "#c88c1e", "#1e96aa")


def covisibility_graph(cameras: list[str], frames_seen: dict[str, int], edges: list[dict[str, Any]],
                       reference: str | None = None) -> Figure:
    """Cameras as nodes on an ellipse, labelled with their name and board views; each edge (``{"a", "b",
    "frames"}``) a line as thick as its share of the most shared frames, with the count written on it. The
    reference has a double ring; a camera in no edge is red."""
    figure = new_figure(4.8, 2.2)
    if not cameras:
        return empty_note(figure, "no result yet")
    angles = np.pi + 2 * np.pi * np.arange(len(cameras)) / len(cameras)
    where = {name: (0.62 * np.cos(a), 0.55 * np.sin(a)) for name, a in zip(cameras, angles, strict=True)}
    most = max([e["frames"] for e in edges] or [1])
    linked = {name for edge in edges for name in (edge["a"], edge["b"])}
    with styled():
        ax = figure.add_subplot()
        for edge in edges:
            (x0, y0), (x1, y1) = where[edge["a"]], where[edge["b"]]
            ax.plot([x0, x1], [y0, y1], color="#787878", lw=1 + 7 * edge["frames"] / most, zorder=1)
            ax.text((x0 + x1) / 2, (y0 + y1) / 2, str(edge["frames"]), ha="center", va="center", zorder=2,
                    bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none"})
        for name, (x, y) in where.items():
            colour = NODE_COLOUR if name in linked else ALONE_COLOUR
            ax.scatter([x], [y], s=700, color=colour, zorder=3)
            if name == reference:
                ax.scatter([x], [y], s=1300, facecolors="none", edgecolors=colour, linewidths=1.5, zorder=3)
            below = y <= 0
            ax.text(x, y + (-0.3 if below else 0.3), f"{name}\n{frames_seen.get(name, 0)} views", ha="center",
                    va="top" if below else "bottom", color="#222222" if name in linked else ALONE_COLOUR)
        ax.set_xlim(-1.1, 1.1)
        ax.set_ylim(-1.1, 1.1)
        ax.axis("off")
        ax.set_title("shared frames per pair" + ("  (red: no shared frame)" if set(cameras) - linked else ""))
    return figure


def frame_residual_bars(cameras: list[str], frames: list[dict[str, Any]]) -> Figure:
    """Per-view reprojection RMS (px), one bar per camera and frame, grouped by camera. ``frames`` are the
    result's ``{"camera", "frame", "rms_px", "flagged", ...}``; flagged views (left out of the solve) are red and
    marked with a cross."""
    figure = new_figure(4.8, 1.9)
    views = [f for camera in cameras for f in frames if f["camera"] == camera]
    if not views:
        return empty_note(figure, "no result yet")
    with styled():
        ax = figure.add_subplot()
        x, ticks, labels = 0.0, [], []
        for i, camera in enumerate(cameras):
            mine = [f for f in views if f["camera"] == camera]
            if not mine:
                continue
            positions = x + np.arange(len(mine))
            colours = [OUTLIER if f["flagged"] else CAMERA_COLOURS[i % len(CAMERA_COLOURS)] for f in mine]
            heights = [f["rms_px"] for f in mine]
            ax.bar(positions, heights, width=0.9, color=colours)
            flagged = [(p, h) for p, h, f in zip(positions, heights, mine, strict=True) if f["flagged"]]
            if flagged:
                ax.scatter(*zip(*flagged, strict=True), marker="x", color=OUTLIER, zorder=3)
            ticks.append(float(positions.mean()))
            labels.append(camera)
            x += len(mine) + 2
        ax.set_xticks(ticks, labels)
        ax.set_ylabel("RMS (px)")
        ax.set_title("per-frame RMS (red x: flagged)")
    return figure
