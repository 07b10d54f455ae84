"""A carried board's line in a 2D scanner's plane over time, as the scanner and as a camera see it
(:class:`~.signals.MotionSignal` of kind ``lines``, both in the scanner's frame: x forward, y left, z up, m).

A 2D scanner's points all lie in its plane z = 0; a board crossing that plane shows as one segment, whose direction
in the plane is the scanner's signal. The camera's is the direction along which the board's plane cuts the scan
plane: the board's normal from PnP rotated into the scanner's frame by the rig's current ``T_camera_lidar`` (here
camera from scanner) and crossed with the scanner's z axis (``n x z``, the normal turned towards the scanner).

The segment is the LiDAR-camera target solve's own line segmentation (:func:`~.board_signals.board_in_scans`: a
RANSAC line in the scan plane facing the way the nearest camera frame's board faces, within
:data:`~.board_signals.REGION_MARGIN_M` of where that frame puts the plate, the clocks not yet lined up, refined by
least squares on its inliers; at least :data:`~.board_signals.MIN_LINE_POINTS` points), and its direction the
inliers' principal axis. A line has no way round: its sign is taken to agree with the camera's direction at the
nearest frame (within 90 deg; a board turning at 1 rad/s moves 29 deg in the largest offset searched). Scans
without such a segment, and camera frames whose board lies within :data:`MAX_BOARD_TILT_DEG` of flat in the scan
plane (its cut's direction ill-defined), are skipped.

**The sweep's skew.** A spinning scanner's beam crosses the board in a few milliseconds (20 deg of an 8 Hz turn:
7 ms), and a board moving towards it meanwhile is measured turned: with the beam taking ``tau`` s per rad of
azimuth (anticlockwise; ``tau = ±1 / (2 pi f)`` for a scanner spinning at ``f`` Hz), the line at distance ``c`` along
its normal ``m`` (``m . x = c``), its segment's centre at ``x_c``, comes out turned (anticlockwise) by
``tau * g`` with ``g = -(dc/dt - dm/dt . x_c) c / |x_c|^2`` (rad/s). A board carried at 0.8 m/s towards an 8 Hz
scanner 2.5 m away is seen turned by 0.4 deg, as much as the scanner's noise, and following the board's motion,
which the timing then follows too. The camera's board poses give ``g`` on the camera's clock (central differences),
so the camera's line is turned by ``tau * g`` to predict what the scanner sees. ``tau`` is fitted, neither the
spin's sense nor its rate (captures may skip scans) taken as known: the signals are aligned and the residual angles
regressed on ``g`` at the aligned times, :data:`SWEEP_ROUNDS` times. On twenty simulated 18 s recordings (8 Hz
scanner, 15 Hz camera, 37 ms apart) the offset erred by up to 8.1 ms without it (6 of 20 beyond 2 ms, two of them
by over 3 sigma and judged trusted) and by at most 1.6 ms with it (0.9 ms RMS, sigma 0.55-1.05 ms, all within 2
sigma); ``tau`` came back within 27 % of the true -19.9 ms per rad.

The moment the beam crosses the board also depends on where the board is (10 deg of azimuth is 3.5 ms at 8 Hz):
the offset found holds for where the board was carried (straight ahead, as the simulated scanner's stamp).

The signal is one angle a sample: only turning the board about the scan plane's normal (a vertical axis, yaw)
moves it; tilting it forward or turning it about its own normal does not. The alignment refuses a line that did
not turn (:data:`~.alignment.MIN_TURN_DEG`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from backend.calib.lidar_camera.target import plate_centre_and_half_size
from backend.calib.time_offset.alignment import align_signals, sample_signal
from backend.calib.time_offset.board_signals import board_in_scans
from backend.calib.time_offset.signals import MotionSignal, facing_normals
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.transforms import invert

MAX_BOARD_TILT_DEG = 60.0
"""Largest angle (deg) of the board's plane from upright (its normal out of the scan plane) for a camera frame's cut
direction to count."""
SWEEP_ROUNDS = 3
"""Rounds of aligning and fitting the sweep's ``tau`` (on the simulated recordings the second moved it by up to a
quarter, the third by up to 6 %, a fourth would by about 1 %)."""


@dataclass(frozen=True)
class BoardCuts:
    """Where the camera puts the board's cut through the scan plane, frame by frame (the scanner's frame)."""

    t_s: np.ndarray
    """(K,) increasing frame times (s, the camera's clock)."""
    T_camera_boards: np.ndarray
    """(K, 4, 4) the board's poses from PnP (m), in the same order."""
    directions: np.ndarray
    """(K, 3) unit directions of the cut (z = 0): the board's normal, turned towards the scanner, crossed with z."""
    upright: np.ndarray
    """(K,) bool: the board within :data:`MAX_BOARD_TILT_DEG` of upright, its cut's direction well defined."""
    skew_rates: np.ndarray
    """(K,) ``g`` (rad/s): a beam taking ``tau`` s per rad of azimuth sees the cut turned by ``tau * g``."""

    def signal(self, sensor: str, tau_s_per_rad: float) -> MotionSignal:
        """The camera's ``lines`` signal as a scanner sweeping at ``tau_s_per_rad`` sees the board."""
        angle = tau_s_per_rad * self.skew_rates[self.upright]
        x, y = self.directions[self.upright, 0], self.directions[self.upright, 1]
        turned = np.column_stack([np.cos(angle) * x - np.sin(angle) * y, np.sin(angle) * x + np.cos(angle) * y,
                                  np.zeros(len(x))])
        return MotionSignal(sensor, "lines", self.t_s[self.upright], turned)


def planar_scans(scans: Sequence[np.ndarray], name: str) -> bool:
    """Whether ``scans`` (each (N, 3+), m) are a 2D scanner's (every point of every non-empty scan at z = 0) or a 3D
    LiDAR's (none at z = 0 throughout); :class:`InputError` naming ``name`` for a mix of both."""
    flat = [not np.any(np.asarray(points)[:, 2]) for points in scans if len(points)]
    if any(flat) and not all(flat):
        raise InputError(f"{sum(flat)} of {len(flat)} clouds have all their points at z = 0 (a 2D scanner's) and the "
                         "others not (a 3D LiDAR's): expected one sensor's scans", name)
    return bool(flat) and all(flat)


def board_cuts(board: BoardSpec, t_s: np.ndarray, T_camera_boards: np.ndarray, T_camera_lidar: np.ndarray
               ) -> BoardCuts:
    """The cuts of the boards at ``T_camera_boards`` (K, 4, 4, m) at times ``t_s`` (s) through the scan plane of the
    scanner at ``T_camera_lidar`` (4x4, m), in time order."""
    order = np.argsort(t_s)
    t, T_camera_boards = np.asarray(t_s, float)[order], np.asarray(T_camera_boards, float)[order]
    T = invert(np.asarray(T_camera_lidar, float)) @ T_camera_boards  # T_lidar_board
    centre_board, _ = plate_centre_and_half_size(board, 0.0)
    centres = T[:, :3, :2] @ centre_board + T[:, :3, 3]
    normals = facing_normals(T[:, :3, 2], centres)
    in_plane = np.hypot(normals[:, 0], normals[:, 1])
    m = normals[:, :2] / np.fmax(in_plane, 1e-12)[:, None]
    c = np.sum(normals * centres, axis=1) / np.fmax(in_plane, 1e-12)  # the cut: m . x = c
    along = np.column_stack([m[:, 1], -m[:, 0]])  # n x z
    middle = c[:, None] * m + np.sum(centres[:, :2] * along, axis=1, keepdims=True) * along  # the plate centre's foot
    drift = np.gradient(c, t) - np.sum(np.gradient(m, t, axis=0) * middle, axis=1)
    skew = -drift * c / np.fmax(np.sum(middle**2, axis=1), 1e-12)
    return BoardCuts(t, T_camera_boards, np.column_stack([along, np.zeros(len(t))]),
                     in_plane >= np.cos(np.radians(MAX_BOARD_TILT_DEG)), skew)


def scanner_lines(sensor: str, board: BoardSpec, scan_t_s: np.ndarray, scans: Sequence[np.ndarray], cuts: BoardCuts,
                  T_camera_lidar: np.ndarray, progress: ProgressCallback = no_progress) -> MotionSignal:
    """The scanner's ``lines`` signal: each scan's board segment's direction, its sign agreeing with the camera's
    cut at the nearest frame."""
    found = [(k, nearest, points) for k, nearest, points in board_in_scans(
        board, scan_t_s, scans, cuts.t_s, cuts.T_camera_boards, T_camera_lidar, progress) if cuts.upright[nearest]]
    directions = np.zeros((len(found), 3))
    for row, (_, nearest, points) in enumerate(found):
        along = np.linalg.svd(points[:, :2] - points[:, :2].mean(axis=0), full_matrices=False)[2][0]
        directions[row, :2] = along if along @ cuts.directions[nearest, :2] >= 0 else -along
    return MotionSignal(sensor, "lines", np.asarray(scan_t_s, float)[[k for k, _, _ in found]], directions)


def fit_sweep(cuts: BoardCuts, camera: str, scanner: MotionSignal, max_offset_s: float = 0.5) -> float:
    """The sweep's ``tau`` (s per rad of anticlockwise azimuth) that best predicts ``scanner``'s lines from the
    camera's ``cuts``: aligned and regressed :data:`SWEEP_ROUNDS` times (see the module's notes)."""
    tau = 0.0
    for _ in range(SWEEP_ROUNDS):
        predicted = cuts.signal(camera, tau)
        aligned = align_signals(predicted, scanner, max_offset_s=max_offset_s)
        at, inside = sample_signal(predicted, scanner.t_s - aligned.offset_s)
        seen = scanner.vectors @ aligned.R_a_b.T
        residual = np.arctan2(at[:, 0] * seen[:, 1] - at[:, 1] * seen[:, 0], np.sum(at * seen, axis=1))[inside]
        g = np.interp(scanner.t_s[inside] - aligned.offset_s, cuts.t_s[cuts.upright], cuts.skew_rates[cuts.upright])
        tau += float(residual @ g / max(float(g @ g), 1e-12))
    return tau


def scan_line_signals(camera: str, scanner: str, board: BoardSpec, scan_t_s: np.ndarray, scans: Sequence[np.ndarray],
                      camera_t_s: np.ndarray, T_camera_boards: np.ndarray, T_camera_lidar: np.ndarray,
                      max_offset_s: float = 0.5,
                      progress: ProgressCallback = no_progress) -> tuple[MotionSignal, MotionSignal]:
    """The camera's and the scanner's ``lines`` signals from the camera's board poses (``T_camera_boards`` (K, 4, 4,
    m) at ``camera_t_s``, s) and the scanner's scans (each (N, 3+), m, z = 0) at ``scan_t_s`` (s), through
    ``T_camera_lidar`` (camera from scanner, 4x4, m); the camera's predicts the sweep's skew, fitted with offsets
    searched within ``±max_offset_s`` (s)."""
    cuts = board_cuts(board, camera_t_s, T_camera_boards, T_camera_lidar)
    lines = scanner_lines(scanner, board, scan_t_s, scans, cuts, T_camera_lidar, lambda f, m: progress(0.9 * f, m))
    tau = fit_sweep(cuts, camera, lines, max_offset_s)
    progress(1.0, f"the scanner's sweep: {1e3 * tau:+.2f} ms per rad"
                  + (f" (a turn in {2e3 * np.pi * abs(tau):.0f} ms)" if tau else ""))
    return cuts.signal(camera, tau), lines
