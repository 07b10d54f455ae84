"""The LiDAR-camera target solve's per-pose evidence: each pose's board as the LiDAR saw it, in the board's plane,
against the plate's outline, with its fit and how far the solve without it moves the result. The studio shows it
beside a target result; the report draws it for every accepted one."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from backend.plots.render import OUTLIER, empty_note, new_figure, styled

if TYPE_CHECKING:
    from backend.calib.lidar_camera.target_evidence import PoseEvidence

COLUMNS = 4
"""Poses drawn per row."""
OFFSET_RANGE_MM = 30.0
"""The face points' colour scale: their distance from the camera's board plane, +-this (mm)."""
FLAG_SIGMAS = 3.0
"""A pose whose leave-one-out re-solve moves the result more than this many Jacobian sigmas is titled in red."""


def _caption(fit: dict) -> str:
    """Two lines under a pose's name: its fit and how far the solve without it moves the result."""
    line = (f"{fit['plane_points']} pts, plane {1e3 * fit['plane_rms_m']:.1f} mm, {fit['edge_points']} ends "
            f"{1e3 * fit['edge_rms_m']:.1f} mm")
    if fit.get("without_m") is None:
        return line + "\nno leave-one-out re-solve"
    return (line + f"\nwithout it: {1e3 * fit['without_m']:.1f} mm, {fit['without_deg']:.2f} deg "
            f"({fit['without_sigmas']:.1f} sigma)")


def pose_evidence_figure(evidence: list[PoseEvidence], title: str) -> Figure:
    """One panel per pose in its board's frame (m): the face points coloured by their distance from the camera's
    board plane, the scan lines' ends (crosses), the fitted plate outline (solid) and the printed pattern (dashed);
    titled with the pose's name and :func:`_caption`, in red when the pose alone moves the result beyond
    :data:`FLAG_SIGMAS`."""
    rows = max(1, math.ceil(len(evidence) / COLUMNS))
    figure = new_figure(2.4 * min(max(len(evidence), 1), COLUMNS), 2.6 * rows + 0.4)
    if not evidence:
        return empty_note(figure, "no pose to show")
    with styled():
        figure.suptitle(title)
        scatter = None
        for k, pose in enumerate(evidence):
            ax = figure.add_subplot(rows, COLUMNS, k + 1)
            ax.add_patch(Rectangle(tuple(pose.plate_centre - pose.plate_half), *(2 * pose.plate_half), fill=False,
                                   lw=1.0, ec="#222222"))
            ax.add_patch(Rectangle(tuple(pose.pattern_origin), *pose.pattern_size, fill=False, lw=0.7, ls="--",
                                   ec="#888888"))
            if len(pose.face_board):
                scatter = ax.scatter(pose.face_board[:, 0], pose.face_board[:, 1], c=1e3 * pose.face_board[:, 2],
                                     s=3, cmap="coolwarm", vmin=-OFFSET_RANGE_MM, vmax=OFFSET_RANGE_MM)
            if len(pose.edges_board):
                ax.scatter(pose.edges_board[:, 0], pose.edges_board[:, 1], marker="x", s=14, lw=0.8, c="#111111")
            flagged = (pose.fit.get("without_sigmas") or 0.0) > FLAG_SIGMAS
            note = f"\nnot found again: {pose.missing}" if pose.missing else ""
            ax.set_title(f"{pose.name}\n{_caption(pose.fit)}{note}", fontsize=6,
                         color=OUTLIER if flagged else "#222222")
            reach = np.max(pose.plate_half) * 1.6
            ax.set_xlim(pose.plate_centre[0] - reach, pose.plate_centre[0] + reach)
            ax.set_ylim(pose.plate_centre[1] - reach, pose.plate_centre[1] + reach)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=5)
        if scatter is not None:
            figure.colorbar(scatter, ax=figure.axes, shrink=0.6, label="distance from the camera's board plane (mm)")
    return figure
