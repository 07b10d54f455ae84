"""A board carried through a camera's and a LiDAR's views, each on its own clock: the time offset's test case.

The board's pose in the LiDAR's frame moves along sums of sines (turning up to about 30 deg about every axis, its
centre 2-3 m ahead), so the truth is known at any instant. The camera, rigidly beside the LiDAR by
``T_camera_lidar``, sees the board's corners at ``camera_hz`` (pixel noise ``pixel_sigma``), stamped by its own
clock. The LiDAR is a 16-beam spinner (VLP-16 elevations, 0.2 deg steps, 10 Hz) that fires each shot at its own
instant: the board's pose is taken at every shot's time (so a moving board smears as in a real scan), and a scan is
stamped when its beam passes straight ahead (azimuth 0, where the board is carried), on a clock that reads
``offset_s`` more than the camera's (``t_lidar = t_camera + offset_s``). Only the sector ahead is cast, against the
plate alone (analytic ray-plane hits, range noise ``range_sigma_m``): the solver only looks there.

A 2D scanner (a YDLiDAR-like 360 deg planar scanner, 0.25 deg steps, 8 Hz) sits 8 cm below the camera by
``T_camera_scanner``, its scan plane level with the LiDAR's x-y plane but for a degree's tilt. It too fires each shot
at its own instant and stamps a scan when its beam passes straight ahead, on its own clock (``t_scanner = t_camera +
scanner_offset_s``); its points lie in its plane (z = 0). The board's centre rises and falls across the scan plane's
height (about 0.2 m either way) while its 0.6 m tall plate straddles it, and its turn about the vertical (yaw, up to
about 30 deg) turns its line in the scan plane; ``yaw=False`` tilts and rolls the board alone, leaving that line
still.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.board.detection import Detection
from backend.calib.camera_imu.observations import BoardObservations
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import invert, make_T, transform_points
from backend.sim.board_renderer import plate_corners_m

BOARD = "checkerboard:7x5:0.1"
CAMERA = CameraIntrinsics("pinhole-radtan", 1280, 720, np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 1]]),
                          np.array([-0.05, 0.01, 0.0, 0.0, 0.0]))
T_CAMERA_LIDAR = make_T(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
                        @ Rotation.from_euler("zyx", [1.5, -2.0, 0.8], degrees=True).as_matrix(), [0.02, -0.12, -0.06])
"""The camera 12 cm below the LiDAR, looking along its x axis, turned by a degree or two."""
T_CAMERA_SCANNER = T_CAMERA_LIDAR @ make_T(Rotation.from_euler("zyx", [-2.0, 1.2, -0.8], degrees=True).as_matrix(),
                                           [0.08, 0.01, -0.2])
"""The 2D scanner 8 cm below the camera (20 cm below the LiDAR), its axes the LiDAR's turned by a degree or two."""
SCANNER_STEP_DEG = 0.25
ELEVATIONS_DEG = np.arange(-15.0, 16.0, 2.0)
SECTOR_DEG = 45.0
"""Half-width (deg) of the sector ahead that is cast."""
AZIMUTH_STEP_DEG = 0.2


@dataclass(frozen=True)
class MovingBoardRecording:
    board: BoardSpec
    camera: CameraIntrinsics
    T_camera_lidar: np.ndarray
    offset_s: float
    """``t_lidar = t_camera + offset_s`` (s)."""
    camera_t_s: np.ndarray
    """(K,) frame stamps on the camera's clock (s)."""
    detections: list[Detection]
    scan_t_s: np.ndarray
    """(S,) scan stamps on the LiDAR's clock (s)."""
    scans: list[np.ndarray]
    """(N, 3) points of each scan (m, LiDAR frame)."""
    T_camera_scanner: np.ndarray
    """The 2D scanner's mounting on the camera (4x4, m)."""
    scanner_offset_s: float
    """``t_scanner = t_camera + scanner_offset_s`` (s)."""
    scanner_t_s: np.ndarray
    """(P,) the 2D scanner's scan stamps on its clock (s)."""
    scanner_scans: list[np.ndarray]
    """(N, 3) points of each of its scans (m, the scanner's frame, z = 0)."""

    def observations(self) -> BoardObservations:
        """The camera's detections as the camera-IMU solve's observations (its detections CSV's rows)."""
        return BoardObservations(self.camera_t_s, np.repeat(np.arange(len(self.detections)),
                                                            [len(d.ids) for d in self.detections]),
                                 np.vstack([d.corners_px for d in self.detections]),
                                 np.vstack([d.object_points(self.board) for d in self.detections]).astype(float))


def board_pose_lidar(t_s: np.ndarray, seed: int = 0, board: str = BOARD, yaw: bool = True) -> np.ndarray:
    """``T_lidar_board`` (N, 4, 4) of ``board`` at true times ``t_s`` (s): the print facing the sensors (board z
    along the LiDAR's x, board x to its right, y down), swinging about every axis (with ``yaw=False`` about the
    LiDAR's x and y axes alone, its normal kept in the LiDAR's x-z plane)."""
    rng = np.random.default_rng([seed, 4242])
    frequencies = rng.uniform(0.2, 0.7, size=(2, 3, 2))
    phases = rng.uniform(0, 2 * np.pi, size=(2, 3, 2))
    angle = 2 * np.pi * frequencies[None] * np.asarray(t_s)[:, None, None, None] + phases[None]
    waves = np.sin(angle).sum(axis=3)
    R_facing = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # columns: board x, y, z in LiDAR axes
    swing = np.radians(14.0) * waves[:, 0]
    turn = Rotation.from_rotvec(swing) if yaw else Rotation.from_euler("xy", swing[:, :2])  # the latter Ry @ Rx
    R = turn.as_matrix() @ R_facing
    spec = BoardSpec.parse(board)
    centre_board = np.r_[spec.outer_origin_m[:2] + np.asarray(spec.size_m) / 2, 0.0]
    centre = np.array([2.5, 0.0, -0.1]) + np.array([0.25, 0.2, 0.1]) * waves[:, 1]
    T = np.tile(np.eye(4), (len(t_s), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = centre - np.einsum("nij,j->ni", R, centre_board)
    return T


def sector_rays() -> tuple[np.ndarray, np.ndarray]:
    """The spinner's unit rays (N, 3) in the sector ahead (LiDAR frame) and each one's azimuth (N,) (rad, clockwise
    from x, as the beam turns)."""
    azimuth = np.radians(np.arange(-SECTOR_DEG, SECTOR_DEG + 1e-9, AZIMUTH_STEP_DEG))
    az, el = (a.ravel() for a in np.meshgrid(azimuth, np.radians(ELEVATIONS_DEG)))
    return np.column_stack([np.cos(el) * np.cos(az), -np.cos(el) * np.sin(az), np.sin(el)]), az


def planar_rays() -> tuple[np.ndarray, np.ndarray]:
    """The 2D scanner's unit rays (N, 3, z = 0) over its full turn (its frame) and each one's azimuth (N,) (rad,
    clockwise from x, -pi to pi, as the beam turns)."""
    azimuth = np.radians(np.arange(-180.0, 180.0, SCANNER_STEP_DEG))
    return np.column_stack([np.cos(azimuth), -np.sin(azimuth), np.zeros(len(azimuth))]), azimuth


def scan_plate(board: BoardSpec, T_lidar_board: np.ndarray, rays: np.ndarray, rng: np.random.Generator,
               range_sigma_m: float) -> np.ndarray:
    """The returns (M, 3) (m, LiDAR frame) of ``rays`` (N, 3) from the origin on the board's plate (print and white
    margin, :func:`~backend.sim.board_renderer.plate_corners_m`), the board at ``T_lidar_board`` (4x4, or (N, 4, 4)
    one per ray), with range noise ``range_sigma_m``."""
    T = np.broadcast_to(T_lidar_board, (len(rays), 4, 4))
    corners = plate_corners_m(board)
    lo, hi = corners[:, :2].min(axis=0), corners[:, :2].max(axis=0)
    normal, origin = T[:, :3, 2], T[:, :3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.sum(normal * origin, axis=1) / np.sum(normal * rays, axis=1)
    hits = rays * distance[:, None]
    local = np.einsum("nji,nj->ni", T[:, :3, :3], hits - origin)[:, :2]
    on_plate = (distance > 0) & np.all((local >= lo) & (local <= hi), axis=1)
    measured = distance[on_plate] + rng.normal(0, range_sigma_m, int(on_plate.sum()))
    return rays[on_plate] * measured[:, None]


def simulate_moving_board(duration_s: float = 20.0, offset_s: float = 0.037, seed: int = 0, camera_hz: float = 15.0,
                          scan_hz: float = 10.0, pixel_sigma: float = 0.3, range_sigma_m: float = 0.01,
                          scanner_offset_s: float = -0.021, scanner_hz: float = 8.0,
                          yaw: bool = True) -> MovingBoardRecording:
    """A recording of ``duration_s`` (camera clock from 500 s), the 2D scanner's scans at ``scanner_hz`` among it;
    ``yaw=False`` never turns the board about the vertical."""
    rng = np.random.default_rng(seed)
    board = BoardSpec.parse(BOARD)
    epoch = 500.0
    t_camera = np.arange(0.0, duration_s, 1.0 / camera_hz)
    grid = board.object_points.astype(float)
    detections = []
    for T_lidar_board in board_pose_lidar(t_camera, seed, yaw=yaw):
        pixels = CAMERA.project(transform_points(T_CAMERA_LIDAR @ T_lidar_board, grid))
        pixels += rng.normal(0, pixel_sigma, pixels.shape)
        detections.append(Detection(pixels, np.arange(len(grid)), (CAMERA.width, CAMERA.height)))

    rays, azimuth = sector_rays()
    t_scan = np.arange(0.3, duration_s - 0.3, 1.0 / scan_hz)
    scans = [scan_plate(board, board_pose_lidar(t + azimuth / (2 * np.pi) / scan_hz, seed, yaw=yaw), rays, rng,
                        range_sigma_m)  # each shot sees the board of its instant
             for t in t_scan]

    scanner_rng = np.random.default_rng([seed, 2])  # its own draws: the camera's and the LiDAR's stay as they were
    T_scanner_lidar = invert(T_CAMERA_SCANNER) @ T_CAMERA_LIDAR
    rays, azimuth = planar_rays()
    t_scanner = np.arange(0.3, duration_s - 0.3, 1.0 / scanner_hz)
    scanner_scans = [scan_plate(board, T_scanner_lidar @ board_pose_lidar(t + azimuth / (2 * np.pi) / scanner_hz, seed,
                                                                           yaw=yaw), rays, scanner_rng, range_sigma_m)
                     for t in t_scanner]
    return MovingBoardRecording(board, CAMERA, T_CAMERA_LIDAR, offset_s, epoch + t_camera, detections,
                                epoch + offset_s + t_scan, scans, T_CAMERA_SCANNER, scanner_offset_s,
                                epoch + scanner_offset_s + t_scanner, scanner_scans)
