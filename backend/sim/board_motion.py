"""Where the simulated board goes, and where its corners truly land in the image.

:func:`board_poses` imitates a person waving a board in front of a camera for an
intrinsic calibration: near and far, tilted, rotated in plane, and covering the
whole image including its corners, with the whole plate always in view.
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import undistort_exact, visible_radius
from backend.core.transforms import make_T, transform_points
from backend.sim.board_renderer import plate_corners_m

_CELL_EDGES = np.array([0.0, 0.08, 0.92, 1.0])
"""Along each axis (as fractions of the image size), the target for the board centre is
drawn from one of three bands: at one border, in the middle, at the other border."""
_MAX_ATTEMPTS = 60
"""How many times a board too large to fit is moved 5 % further away before giving up."""
_COVER_CELLS = np.array([0.0, 0.04, 0.3, 0.7, 0.96, 1.0])
""":func:`covering_poses`' 5x5 target cells along each axis (fractions of the image size): the border, between,
the middle, between, the other border."""
_COVER_FILL = {0: (0.50, 0.85), 1: (0.30, 0.55), 2: (0.12, 0.26)}
"""Share of the image width the print fills (at the lens's local scale) by ring of the 5x5 cells: middle,
between, border. A board at the border must be small for its outermost corners to reach the border's cells."""
_COVER_CORNER_FILL = (0.08, 0.18)
"""The fill in the four corner cells: only a small board, turned towards the corner, reaches into it."""


def project_corners(camera: CameraIntrinsics, board: BoardSpec, T_camera_board: np.ndarray) -> np.ndarray:
    """True (N, 2) pixels of the board's inner corners, in :attr:`BoardSpec.object_points` order."""
    return camera.project(transform_points(T_camera_board, board.object_points.astype(float)))


def plate_in_view(camera: CameraIntrinsics, board: BoardSpec, T_camera_board: np.ndarray, margin_px: float) -> bool:
    """Whether the whole plate (print plus white margin) is in front of the camera and inside the image.

    The plate outline is sampled densely, since distortion bends its straight
    edges; it must be at least 5 cm in front of the camera, within the widest angle
    any pixel sees, and ``margin_px`` (px) inside the image border.
    """
    outline_camera = transform_points(T_camera_board, _plate_outline(board))
    if np.any(outline_camera[:, 2] <= 0.05):
        return False
    normalised = outline_camera[:, :2] / outline_camera[:, 2:]
    # Beyond the largest angle the image sees, the lens model may fold points back into the image.
    if np.any(np.linalg.norm(normalised, axis=1) > visible_radius(camera)):
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
    which sets the distance: about 0.4 to 1.9 m for the 0.4 m demo board in
    ``cam_front``), tilts about the board's x and y axes (up to ``max_tilt_deg``,
    relative to squarely facing the camera along the line of sight), an in-plane
    rotation (up to ``max_roll_deg``) and a target pixel for the board centre in
    one of 3x3 image cells (see ``_CELL_EDGES``; each cell once per nine poses).
    The board slides from the image centre towards the target as far as it stays
    wholly in view (:func:`plate_in_view`), so boards aimed at a corner end up
    touching it; a board too large to fit even at the centre is moved back until
    it does. The first ``k`` poses do not depend on ``n``.
    """
    rng = np.random.default_rng(seed)
    poses: list[np.ndarray] = []
    cells: list[int] = []
    for _ in range(n):
        if not cells:
            cells = rng.permutation(9).tolist()
        cell_index = cells.pop()
        low = _CELL_EDGES[[cell_index % 3, cell_index // 3]]
        high = _CELL_EDGES[[cell_index % 3 + 1, cell_index // 3 + 1]]
        target_px = rng.uniform(low, high) * [camera.width - 1, camera.height - 1]
        fill_fraction = rng.uniform(*fill)
        tilt = np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, size=2))
        # In a border cell, the board's outer edge leans away from the camera (tilt about
        # board x: +y edge recedes for positive angles; about board y: +x edge for negative).
        side = np.array([cell_index // 3 - 1, 1 - cell_index % 3])
        tilt = np.where(side != 0, side * np.abs(tilt), tilt)
        roll = np.radians(rng.uniform(-max_roll_deg, max_roll_deg))
        R_facing_board = Rotation.from_euler("XYZ", [tilt[0], tilt[1], roll]).as_matrix()
        poses.append(_pose_toward(camera, board, fill_fraction, R_facing_board, target_px, margin_px)[0])
    return poses


def covering_poses(camera: CameraIntrinsics, board: BoardSpec, seed: int, *, max_tilt_deg: float = 40.0,
                   max_roll_deg: float = 20.0, margin_px: float = 4.0) -> Iterator[np.ndarray]:
    """Endless poses ``T_camera_board`` (4x4, m) of a board taken to every part of the image; deterministic by
    ``seed``. Each takes about 20 ms to plan, so a device plans them as it shows them.

    Like :func:`board_poses`, but the target pixel is drawn in one of 5x5 cells (:data:`_COVER_CELLS`, each
    once per 25 poses) and the board's size follows the cell (:data:`_COVER_FILL`): large in the middle, small
    at the borders with the outer edge leaning 15-45 deg away, smallest in the corners and turned 10-30 deg
    towards them. The fill is the print's width in pixels at the lens's scale where the board lands, so a
    wide lens's stretched borders get boards as small as the middle's, moved back until they are. With
    about 6 poses per cell (150 poses), corners land in at least 95 % of the coverage heat map's cells of
    the demo's lenses, as the studio's guidance asks.
    """
    rng = np.random.default_rng(seed)
    cells: list[int] = []
    while True:
        if not cells:
            cells = rng.permutation(25).tolist()
        cell = np.array(divmod(cells.pop(), 5))[::-1]  # (column, row) in 0..4
        side = np.sign(cell - 2)
        ring = int(np.abs(cell - 2).max())
        target_px = rng.uniform(_COVER_CELLS[cell], _COVER_CELLS[cell + 1]) * [camera.width - 1, camera.height - 1]
        fill_fraction = rng.uniform(*_COVER_FILL[ring])
        tilt = np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, size=2))
        if ring == 2:  # the outer edge leans away (see board_poses for the signs), about board x then y
            outward = np.array([side[1], -side[0]])
            tilt = np.where(outward != 0, outward * np.radians(rng.uniform(15, 45, size=2)), tilt)
        roll = np.radians(rng.uniform(-max_roll_deg, max_roll_deg))
        if np.all(np.abs(cell - 2) == 2):
            roll = np.radians(side[0] * side[1] * rng.uniform(10, 30))
            fill_fraction = rng.uniform(*_COVER_CORNER_FILL)
        R_facing_board = Rotation.from_euler("XYZ", [tilt[0], tilt[1], roll]).as_matrix()
        T, distance_m = _pose_toward(camera, board, fill_fraction, R_facing_board, target_px, margin_px)
        wanted_square_px = fill_fraction * camera.width / (board.corner_grid[0] + 1)
        for _ in range(3):  # back off while the lens's local scale shows the squares larger than wanted
            ratio = _square_px(camera, board, T) / wanted_square_px
            if ratio <= 1.05:
                break
            further = _place(camera, board, distance_m * ratio, R_facing_board, target_px, margin_px)
            if further is None:
                break
            T, distance_m = further, distance_m * ratio
        yield T


def _pose_toward(camera: CameraIntrinsics, board: BoardSpec, fill_fraction: float, R_facing_board: np.ndarray,
                 target_px: np.ndarray, margin_px: float) -> tuple[np.ndarray, float]:
    """:func:`_place`'s pose at the distance (m) where the print fills ``fill_fraction`` of the image width at
    the centre's scale, moved back 5 % at a time until the plate fits; returns the pose and that distance."""
    for _ in range(_MAX_ATTEMPTS):
        distance_m = camera.K[0, 0] * board.size_m[0] / (fill_fraction * camera.width)
        T = _place(camera, board, distance_m, R_facing_board, target_px, margin_px)
        if T is not None:
            return T, distance_m
        fill_fraction *= 0.95
    raise ValueError(f"cannot fit board {board} in the {camera.width}x{camera.height} image")


def _square_px(camera: CameraIntrinsics, board: BoardSpec, T_camera_board: np.ndarray) -> float:
    """Median side (px) of the board's squares along its rows, as the camera sees them at ``T_camera_board``."""
    cols, rows = board.corner_grid
    corners_px = project_corners(camera, board, T_camera_board).reshape(rows, cols, 2)
    return float(np.median(np.linalg.norm(np.diff(corners_px, axis=1), axis=2)))


@lru_cache(maxsize=8)
def _plate_outline(board: BoardSpec, per_edge: int = 24) -> np.ndarray:
    """(4 * per_edge, 3) board-frame points (m) evenly along the plate's edge (cached: do not modify)."""
    corners = plate_corners_m(board)
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)[:, None]
    return np.concatenate([a + t * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True)])


def _place(
    camera: CameraIntrinsics,
    board: BoardSpec,
    distance_m: float,
    R_facing_board: np.ndarray,
    target_px: np.ndarray,
    margin_px: float,
) -> np.ndarray | None:
    """``T_camera_board`` with the plate centre about ``distance_m`` (m) away, as close to pixel ``target_px`` as fits.

    Before ``R_facing_board`` turns it, the board squarely faces the camera along
    the ray of ``target_px``. It then slides, at a fixed depth and orientation,
    from the image centre towards ``target_px`` until the plate would leave the
    view, then along x alone and along y alone, so a board aimed at a corner ends up
    in it. None if the plate does not fit even at the image centre.
    """
    centre_board = plate_corners_m(board).mean(axis=0)
    target_ray = _unit_ray(camera, target_px)
    x_axis = np.array([1.0, 0.0, 0.0]) - target_ray[0] * target_ray
    x_axis /= np.linalg.norm(x_axis)
    R_camera_board = np.column_stack([x_axis, np.cross(target_ray, x_axis), target_ray]) @ R_facing_board
    depth_m = distance_m * target_ray[2]

    def pose(centre_px: np.ndarray) -> np.ndarray:
        ray = _unit_ray(camera, centre_px)
        return make_T(R_camera_board, depth_m / ray[2] * ray - R_camera_board @ centre_board)

    def slide(start_px: np.ndarray, end_px: np.ndarray) -> np.ndarray:
        """The point furthest towards ``end_px`` (bisection) at which the plate is still in view."""
        if plate_in_view(camera, board, pose(end_px), margin_px):
            return end_px
        fits, leaves = 0.0, 1.0
        for _ in range(10):
            middle = 0.5 * (fits + leaves)
            if plate_in_view(camera, board, pose(start_px + middle * (end_px - start_px)), margin_px):
                fits = middle
            else:
                leaves = middle
        return start_px + fits * (end_px - start_px)

    centre_px = np.array([camera.width - 1.0, camera.height - 1.0]) / 2
    if not plate_in_view(camera, board, pose(centre_px), margin_px):
        return None
    centre_px = slide(centre_px, target_px)
    centre_px = slide(centre_px, np.array([target_px[0], centre_px[1]]))
    centre_px = slide(centre_px, np.array([centre_px[0], target_px[1]]))
    return pose(centre_px)


def _unit_ray(camera: CameraIntrinsics, pixel: np.ndarray) -> np.ndarray:
    """Unit viewing ray (3,) in the optical frame through a distorted ``pixel`` (px)."""
    ray = np.append(undistort_exact(camera, pixel[None, :])[0], 1.0)
    return ray / np.linalg.norm(ray)
