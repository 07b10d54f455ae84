"""Where the simulated board goes, and where its corners truly land in the image.

:func:`board_poses` imitates a person waving a board in front of a camera for an
intrinsic calibration: near and far, tilted, rotated in plane, and covering the
whole image including its corners, with the whole plate always in view.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import make_T, transform_points
from backend.sim.board_renderer import plate_corners_m
from backend.sim.camera_rays import ray_field

_GRID = 3
"""The image is split into _GRID x _GRID cells; every _GRID**2 poses visit each cell once."""
_MAX_ATTEMPTS = 60


def project_corners(camera: CameraIntrinsics, board: BoardSpec, T_camera_board: np.ndarray) -> np.ndarray:
    """True (N, 2) pixels of the board's inner corners, in :attr:`BoardSpec.object_points` order."""
    return camera.project(transform_points(T_camera_board, board.object_points.astype(float)))


def plate_in_view(camera: CameraIntrinsics, board: BoardSpec, T_camera_board: np.ndarray, margin_px: float) -> bool:
    """Whether the whole plate (print plus white margin) is in front of the camera and inside the image.

    The plate outline is sampled densely, since distortion bends its straight
    edges, and must stay ``margin_px`` (px) inside the image border.
    """
    corners = plate_corners_m(board)
    t = np.linspace(0.0, 1.0, 24, endpoint=False)[:, None]
    outline_board = np.concatenate([a + t * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0))])
    outline_camera = transform_points(T_camera_board, outline_board)
    if np.any(outline_camera[:, 2] <= 0.05):
        return False
    normalised = outline_camera[:, :2] / outline_camera[:, 2:]
    # Beyond the largest angle the image sees, the lens model may fold points back into the image.
    if np.any(np.linalg.norm(normalised, axis=1) > ray_field(camera).visible_radius):
        return False
    uv = camera.project(outline_camera)
    inside_u = (uv[:, 0] >= margin_px) & (uv[:, 0] <= camera.width - 1 - margin_px)
    inside_v = (uv[:, 1] >= margin_px) & (uv[:, 1] <= camera.height - 1 - margin_px)
    return bool(np.all(inside_u & inside_v))


def board_poses(
    camera: CameraIntrinsics,
    board: BoardSpec,
    n: int,
    seed: int,
    *,
    fill: tuple[float, float] = (0.15, 0.70),
    max_tilt_deg: float = 40.0,
    max_roll_deg: float = 20.0,
    margin_px: float = 4.0,
) -> list[np.ndarray]:
    """``n`` poses ``T_camera_board`` (4x4, m) of a board waved in front of ``camera``; deterministic by ``seed``.

    Each pose draws how much of the image width the printed board fills (``fill``,
    which sets the distance), tilts about the board's x and y axes (up to
    ``max_tilt_deg``, relative to facing the camera squarely along the line of
    sight) and an in-plane rotation (up to ``max_roll_deg``). The board centre is
    placed in one of 3x3 image cells, every cell once per nine poses, anywhere the
    board fits, so small boards reach the image corners. A pose whose plate would
    leave the image (checked by :func:`plate_in_view`) is moved back and towards
    the centre until it fits.
    """
    rng = np.random.default_rng(seed)
    plate = plate_corners_m(board)
    plate_size_m = plate[2, :2] - plate[0, :2]
    centre_board = np.append(plate[0, :2] + plate_size_m / 2, 0.0)
    poses: list[np.ndarray] = []
    for i in range(n):
        if i % _GRID**2 == 0:
            cells = rng.permutation(_GRID**2)
        cell = np.array([cells[i % _GRID**2] % _GRID, cells[i % _GRID**2] // _GRID])
        spot = (cell + rng.uniform(size=2)) / _GRID
        fill_fraction = rng.uniform(*fill)
        tilt = np.radians([rng.uniform(-max_tilt_deg, max_tilt_deg), rng.uniform(-max_tilt_deg, max_tilt_deg)])
        roll = np.radians(rng.uniform(-max_roll_deg, max_roll_deg))
        R_facing_board = Rotation.from_euler("XYZ", [tilt[0], tilt[1], roll]).as_matrix()
        for _ in range(_MAX_ATTEMPTS):
            T = _place(camera, plate_size_m, centre_board, fill_fraction, spot, R_facing_board)
            if plate_in_view(camera, board, T, margin_px):
                break
            fill_fraction *= 0.95
            spot = 0.5 + 0.95 * (spot - 0.5)
        else:
            raise ValueError(f"cannot fit board {board} in the {camera.width}x{camera.height} image")
        poses.append(T)
    return poses


def _place(
    camera: CameraIntrinsics,
    plate_size_m: np.ndarray,
    centre_board: np.ndarray,
    fill_fraction: float,
    spot: np.ndarray,
    R_facing_board: np.ndarray,
) -> np.ndarray:
    """``T_camera_board`` with the plate centre on the ray through ``spot`` (fractions of the free image area).

    The distance makes the plate ``fill_fraction`` of the image width wide (pinhole
    approximation); ``R_facing_board`` turns the board away from squarely facing
    the camera along that ray.
    """
    focal_px = camera.K[0, 0]
    width_px = fill_fraction * camera.width
    distance_m = focal_px * plate_size_m[0] / width_px
    half_px = 0.5 * np.array([width_px, width_px * plate_size_m[1] / plate_size_m[0]])
    image_px = np.array([camera.width - 1.0, camera.height - 1.0])
    low, high = half_px, np.maximum(image_px - half_px, half_px)
    centre_px = low + spot * (high - low)
    direction = camera.rays(centre_px[None, :])[0]
    x_axis = np.array([1.0, 0.0, 0.0]) - direction[0] * direction
    x_axis /= np.linalg.norm(x_axis)
    R_camera_facing = np.column_stack([x_axis, np.cross(direction, x_axis), direction])
    R_camera_board = R_camera_facing @ R_facing_board
    return make_T(R_camera_board, distance_m * direction - R_camera_board @ centre_board)
