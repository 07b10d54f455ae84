"""Board corners seen by a camera over time, and the board's pose in each frame by PnP."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.tables import parse_table, read_table
from backend.core.transforms import from_rvec_tvec

DETECTION_COLUMNS = ("t_ns", "u_px", "v_px", "x_m", "y_m", "z_m", "tag_id", "corner")
"""The columns of a detections file, in order (``../shared/conventions.md``)."""
MIN_FRAME_CORNERS = 8
"""Corners a frame needs for its board pose to count."""


@dataclass(frozen=True)
class BoardObservations:
    """Every detected corner of a recording, frame by frame, in time order."""

    t_s: np.ndarray
    """(K,) frame times (s) on the camera's clock."""
    frame: np.ndarray
    """(M,) the frame (index into ``t_s``) of each corner."""
    pixels_px: np.ndarray
    """(M, 2) detected corners (px, OpenCV convention)."""
    board_m: np.ndarray
    """(M, 3) the same corners on the board (m, board frame)."""

    def subset(self, frames: np.ndarray) -> BoardObservations:
        """The observations of the frames ``frames`` (indices, increasing), renumbered."""
        keep = np.isin(self.frame, frames)
        renumber = np.full(len(self.t_s), -1)
        renumber[frames] = np.arange(len(frames))
        return BoardObservations(self.t_s[frames], renumber[self.frame[keep]], self.pixels_px[keep],
                                 self.board_m[keep])


def read_detections_csv(path: Path, name: str | None = None) -> BoardObservations:
    """The corners of a detections file (``t_ns, u_px, v_px, x_m, y_m, z_m, tag_id, corner``; frame times in s from
    the epoch of ``t_ns``); :class:`InputError` naming the file for other columns or values that are not finite."""
    shown = name or str(path)
    return _observations(read_table(path, DETECTION_COLUMNS, shown), shown)


def parse_detections_csv(data: bytes, name: str) -> BoardObservations:
    """:func:`read_detections_csv` on a file's bytes (an upload named ``name``)."""
    return _observations(parse_table(data, DETECTION_COLUMNS, name), name)


def _observations(rows: np.ndarray, name: str) -> BoardObservations:
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    if not np.isfinite(rows[:, :6]).all():
        raise InputError(f"{name}: a corner's time, pixel or board point is not a finite number", name)
    times_ns, frame = np.unique(rows[:, 0], return_inverse=True)
    return BoardObservations(times_ns * 1e-9, frame, np.ascontiguousarray(rows[:, 1:3]),
                             np.ascontiguousarray(rows[:, 3:6]))


def board_poses(camera: CameraIntrinsics, observations: BoardObservations) -> tuple[np.ndarray, np.ndarray]:
    """``T_camera_board`` (K, 4, 4; m) of every frame by PnP on undistorted corners, and each frame's RMS
    reprojection (px; NaN where a frame has fewer than :data:`MIN_FRAME_CORNERS` corners or PnP failed)."""
    normalised = camera.undistort_points(observations.pixels_px)
    poses = np.tile(np.eye(4), (len(observations.t_s), 1, 1))
    rms = np.full(len(observations.t_s), np.nan)
    starts = np.searchsorted(observations.frame, np.arange(len(observations.t_s) + 1))
    for k in range(len(observations.t_s)):
        rows = slice(starts[k], starts[k + 1])
        if starts[k + 1] - starts[k] < MIN_FRAME_CORNERS:
            continue
        ok, rvec, tvec = cv2.solvePnP(observations.board_m[rows], normalised[rows], np.eye(3), None)
        if not ok:
            continue
        poses[k] = from_rvec_tvec(rvec, tvec)
        projected = camera.project((observations.board_m[rows] @ poses[k][:3, :3].T) + poses[k][:3, 3])
        rms[k] = float(np.sqrt(np.mean(np.sum((projected - observations.pixels_px[rows]) ** 2, axis=1))))
    return poses, rms


def board_corner_grid(spec: str) -> np.ndarray:
    """(N, 3) every corner (m, board frame, z = 0) a board spec can show: an AprilGrid's tag corners
    (``aprilgrid:COLSxROWS:TAG_SIZE:SPACING``, Kalibr's layout: tag (i, j) from ``(i, j) * size * (1 + spacing)``)
    or a checkerboard's inner corners; :class:`InputError` naming ``--board`` for anything else."""
    parts = spec.split(":")
    if parts[0] == "aprilgrid":
        try:
            cols, rows = (int(v) for v in parts[1].lower().split("x"))
            size_m, spacing = float(parts[2]), float(parts[3])
        except (IndexError, ValueError):
            raise InputError(f"board spec {spec!r}: expected aprilgrid:COLSxROWS:TAG_SIZE:SPACING, e.g. "
                             "aprilgrid:6x6:0.088:0.3", "--board") from None
        if len(parts) != 4 or min(cols, rows) < 1 or not size_m > 0 or not spacing >= 0:
            raise InputError(f"board spec {spec!r}: expected aprilgrid:COLSxROWS:TAG_SIZE:SPACING with positive "
                             "sizes", "--board")
        pitch = size_m * (1 + spacing)
        i, j = np.meshgrid(np.arange(cols), np.arange(rows))
        starts = np.column_stack([i.ravel(), j.ravel()]) * pitch
        offsets = np.array([[0, 0], [size_m, 0], [size_m, size_m], [0, size_m]])
        corners = (starts[:, None, :] + offsets[None]).reshape(-1, 2)
        return np.column_stack([corners, np.zeros(len(corners))])
    from backend.core.boards import BoardSpec

    board = BoardSpec.parse(spec)
    if board.kind != "checkerboard":
        raise InputError(f"board spec {spec!r}: camera-imu takes an aprilgrid or a checkerboard", "--board")
    cols, rows = board.corner_grid
    i, j = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.column_stack([i.ravel() * board.square_m, j.ravel() * board.square_m, np.zeros(cols * rows)])


def check_board_points(observations: BoardObservations, spec: str, name: str, tolerance_m: float = 1e-3) -> None:
    """:class:`InputError` naming the detections file when its board points are not corners of the board ``spec``
    (the wrong board given, or its sizes in other units)."""
    grid = board_corner_grid(spec)
    points = np.unique(observations.board_m, axis=0)
    distance = np.array([np.min(np.linalg.norm(grid - point, axis=1)) for point in points])
    off = distance > tolerance_m
    if off.any():
        first = points[int(np.argmax(off))]
        raise InputError(f"{name}: {int(off.sum())} of its {len(points)} distinct board points are not corners of "
                         f"the board {spec} (the first at "
                         f"({first[0]:.4f}, {first[1]:.4f}, {first[2]:.4f}) m, {1e3 * distance[off].min():.1f} mm or "
                         "more from its nearest corner): give the board the detections were made with", name)
