"""What each board pose of a target solve shows, at the solution: the board's points and edge points in the board's
plane, and the plate's outline they were fitted to.

The studio and the report draw it (:func:`backend.plots.lidar_camera.pose_evidence_figure`) beside each pose's fit
and how far the solve without the pose moves the result (the result's ``diagnostics["poses"]``), so that a pose whose
board points are not the board's (a hand, an arm, the person behind it) can be seen, named and dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from backend.calib.lidar_camera.target import (
    LidarCameraTargetSettings,
    TargetObservation,
    find_board_points,
    outline_distance,
    plate_centre_and_half_size,
)
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.projection import project_cloud
from backend.core.transforms import invert, transform_points


@dataclass
class PoseEvidence:
    """One pose's board as the LiDAR saw it, in the camera's board frame (m) at the solved ``T_camera_lidar``."""

    name: str
    face_board: np.ndarray
    """(N, 3) the board's face points: x, y in the board's plane, z their distance from it (m)."""
    edges_board: np.ndarray
    """(M, 3) the scan lines' end points, likewise."""
    edge_distance_m: np.ndarray
    """(M,) each end point's signed distance to the plate's outline (positive outside)."""
    plate_centre: np.ndarray
    """(2,) and (2,): the plate's outline the edges were fitted to (board x, y; m)."""
    plate_half: np.ndarray
    pattern_origin: np.ndarray
    """(2,) and (2,): the printed pattern's outer corner and size (board x, y; m)."""
    pattern_size: np.ndarray
    fit: dict[str, Any]
    """The pose's record in the result's ``diagnostics["poses"]``: its fit and how far the solve without it moves
    the result."""
    missing: str | None = None
    """Why the board's points could not be found again at the solution (then the arrays are empty), or None."""


def pose_evidence(board: BoardSpec, observations: Sequence[TargetObservation], diagnostics: dict[str, Any],
                  T_camera_lidar: np.ndarray, settings: LidarCameraTargetSettings) -> list[PoseEvidence]:
    """Each solved pose's :class:`PoseEvidence` (in the order of ``diagnostics["poses"]``) at ``T_camera_lidar``
    (4x4, m): its board's points found again as the solve's last round found them (its region margin, the solved
    plate margin ``diagnostics["plate_margin_m"]``). ``observations`` are the poses solved (others are ignored)."""
    margin_m = float(diagnostics.get("plate_margin_m", settings.plate_margin_m))
    at_solution = replace(settings, plate_margin_m=margin_m)
    centre, half = plate_centre_and_half_size(board, margin_m)
    by_name = {o.name: o for o in observations}
    rng = np.random.default_rng(settings.seed)
    evidence = []
    for fit in diagnostics.get("poses", []):
        observation = by_name.get(fit["name"])
        if observation is None:
            continue
        empty = np.zeros((0, 3))
        found, missing = None, None
        try:
            found = find_board_points(observation.points_lidar, observation.T_camera_board, T_camera_lidar, board,
                                      settings.region_margins_m[-1], at_solution, rng, fit["name"])
        except InputError as error:
            missing = error.message
        T_board_lidar = invert(observation.T_camera_board) @ T_camera_lidar
        face = empty if found is None else transform_points(T_board_lidar, found.plane)
        edges = empty if found is None else transform_points(T_board_lidar, found.edges)
        evidence.append(PoseEvidence(fit["name"], face, edges, outline_distance(edges, centre, half), centre, half,
                                     board.outer_origin_m[:2].copy(), np.asarray(board.size_m, float), fit, missing))
    return evidence


IN_IMAGE_SLACK_PX = 10.0
"""A projected board point counts as inside the board's outline in the image within this (px)."""


def share_in_image_outline(points_lidar: np.ndarray, T_camera_lidar: np.ndarray, T_camera_board: np.ndarray,
                           camera: CameraIntrinsics, board: BoardSpec, plate_margin_m: float) -> float:
    """The share of a pose's board points ((N, 3), m, LiDAR frame) that ``T_camera_lidar`` projects inside the plate's
    outline as the camera saw it: the pattern placed by ``T_camera_board`` and grown by ``plate_margin_m``, within
    :data:`IN_IMAGE_SLACK_PX`. A check in the image: it takes the board's outline where the camera saw it, not the
    distance PnP gave it; points of a hand or an arm holding the board fall outside at any transform."""
    origin = board.outer_origin_m[:2] - plate_margin_m
    size = np.asarray(board.size_m, float) + 2 * plate_margin_m
    corners = [origin, origin + [size[0], 0.0], origin + size, origin + [0.0, size[1]], origin]
    s = np.linspace(0.0, 1.0, 60)
    outline = np.vstack([a + np.outer(s, b - a) for a, b in zip(corners[:-1], corners[1:], strict=True)])
    outline_camera = transform_points(T_camera_board, np.column_stack([outline, np.zeros(len(outline))]))
    polygon = camera.project_normalised(outline_camera[:, :2] / outline_camera[:, 2:]).astype(np.float32)
    uv = project_cloud(points_lidar, T_camera_lidar, camera).uv
    if len(uv) == 0:
        return 0.0
    return float(np.mean([cv2.pointPolygonTest(polygon, (float(u), float(v)), True) >= -IN_IMAGE_SLACK_PX
                          for u, v in uv]))


IN_IMAGE_SEARCH_M = 0.15
"""The board's points for :func:`shares_in_image_outline` are searched within this of the plate (m), about each
transform compared."""


def shares_in_image_outline(observation: TargetObservation, transforms: Sequence[np.ndarray],
                            camera: CameraIntrinsics, board: BoardSpec, settings: LidarCameraTargetSettings
                            ) -> list[float]:
    """Several ``T_camera_lidar`` (4x4, m) compared in the image on one pose: the board's points found in its cloud
    about any of them (within :data:`IN_IMAGE_SEARCH_M`, ``settings.plate_margin_m`` the plate's margin), and the
    share of them each puts inside the board's outline as the camera saw it (:func:`share_in_image_outline`). The
    same points for every transform, so a transform is not judged on the points it picked itself."""
    rng = np.random.default_rng(settings.seed)
    found = []
    for T_camera_lidar in transforms:
        try:
            found.append(find_board_points(observation.points_lidar, observation.T_camera_board, T_camera_lidar, board,
                                           IN_IMAGE_SEARCH_M, settings, rng, observation.name).plane)
        except InputError:
            continue
    points = np.unique(np.vstack(found), axis=0) if found else np.zeros((0, 3))
    return [share_in_image_outline(points, T_camera_lidar, observation.T_camera_board, camera, board,
                                   settings.plate_margin_m) for T_camera_lidar in transforms]
