"""Board corners seen by a camera over time, and the board's pose in each frame by PnP."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from backend.calib.board.detection import detect_board
from backend.calib.board.pose import pnp_pose
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.tables import parse_table, read_table
from backend.core.transforms import transform_points
from backend.devices.file_sequence import stamped_files
from backend.devices.image_io import read_image

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


def format_detections_csv(observations: BoardObservations) -> bytes:
    """The observations as a detections file (:func:`read_detections_csv` reads it back; ``tag_id`` 0, ``corner``
    the row's number)."""
    lines = [",".join(DETECTION_COLUMNS)] + [
        f"{round(observations.t_s[f] * 1e9)},{u:.4f},{v:.4f},{x:.6f},{y:.6f},{z:.6f},0,{i}"
        for i, (f, (u, v), (x, y, z)) in enumerate(zip(observations.frame, observations.pixels_px,
                                                       observations.board_m, strict=True))]
    return "\n".join(lines).encode() + b"\n"


def _observations(rows: np.ndarray, name: str) -> BoardObservations:
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    if not np.isfinite(rows[:, :6]).all():
        raise InputError(f"{name}: a corner's time, pixel or board point is not a finite number", name)
    times_ns, frame = np.unique(rows[:, 0], return_inverse=True)
    return BoardObservations(times_ns * 1e-9, frame, np.ascontiguousarray(rows[:, 1:3]),
                             np.ascontiguousarray(rows[:, 3:6]))


def board_poses(camera: CameraIntrinsics, observations: BoardObservations) -> tuple[np.ndarray, np.ndarray]:
    """``T_camera_board`` (K, 4, 4; m) of every frame by PnP (:func:`~backend.calib.board.pose.pnp_pose`), and each
    frame's RMS reprojection (px; NaN where a frame has fewer than :data:`MIN_FRAME_CORNERS` corners or PnP
    failed)."""
    poses = np.tile(np.eye(4), (len(observations.t_s), 1, 1))
    rms = np.full(len(observations.t_s), np.nan)
    starts = np.searchsorted(observations.frame, np.arange(len(observations.t_s) + 1))
    for k in range(len(observations.t_s)):
        rows = slice(starts[k], starts[k + 1])
        if starts[k + 1] - starts[k] < MIN_FRAME_CORNERS:
            continue
        pose = pnp_pose(camera, observations.board_m[rows], observations.pixels_px[rows])
        if pose is None:
            continue
        poses[k] = pose
        projected = camera.project(transform_points(pose, observations.board_m[rows]))
        rms[k] = float(np.sqrt(np.mean(np.sum((projected - observations.pixels_px[rows]) ** 2, axis=1))))
    return poses, rms

def check_board_points(observations: BoardObservations, spec: str, name: str, tolerance_m: float = 1e-3) -> None:
    """:class:`InputError` naming the detections file when its board points are not corners of the board ``spec``
    (the wrong board given, or its sizes in other units). Only where the points lie counts, not which corner each
    is: a file in Kalibr's frame (an AprilGrid's y up from tag 0) holds the same positions as the studio's."""
    grid = BoardSpec.parse(spec).object_points.astype(np.float64)
    points = np.unique(observations.board_m, axis=0)
    distance = np.array([np.min(np.linalg.norm(grid - point, axis=1)) for point in points])
    off = distance > tolerance_m
    if off.any():
        first = points[int(np.argmax(off))]
        raise InputError(f"{name}: {int(off.sum())} of its {len(points)} distinct board points are not corners of "
                         f"the board {spec} (the first at "
                         f"({first[0]:.4f}, {first[1]:.4f}, {first[2]:.4f}) m, {1e3 * distance[off].min():.1f} mm or "
                         "more from its nearest corner): give the board the detections were made with", name)


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".bmp", ".tif", ".tiff")


def detect_image_folder(folder: Path, spec: str, progress: ProgressCallback = no_progress) -> BoardObservations:
    """The board ``spec`` detected in every image of ``folder``, each named by its time stamp in ns (as EuRoC and
    Kalibr's bag extraction name them, ``1403715273262142976.png``); frames without the board are left out.
    :class:`InputError` naming the folder or the file for a name that is not a time stamp or an unreadable image."""
    board = BoardSpec.parse(spec)
    stamped = stamped_files(folder, IMAGE_SUFFIXES, "image", "images", "--images")
    times, frames, pixels, points = [], [], [], []
    for index, (stamp_ns, path) in enumerate(stamped):
        progress(index / len(stamped), f"detecting the board in {path.name}")
        detection = detect_board(read_image(path), board)
        if detection is None:
            continue
        times.append(stamp_ns * 1e-9)
        frames.append(np.full(len(detection.ids), len(times) - 1))
        pixels.append(detection.corners_px)
        points.append(board.object_points[detection.ids].astype(np.float64))
    if not times:
        raise InputError(f"the board {spec} was found in none of the {len(stamped)} images of {folder}", "--images")
    return BoardObservations(np.array(times), np.concatenate(frames), np.concatenate(pixels), np.concatenate(points))
