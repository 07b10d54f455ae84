"""A simulated yard for the demo rig's LiDARs, and the ray-caster that scans it.

The scene is a triangle mesh in the yard's frame (x forward, y left, z up, metres), which is
``base_link`` when the robot stands at the origin (place 0 of :data:`ROBOT_PLACES`; it can be
driven to the others, so that LiDAR-to-LiDAR scenes from several places check each other).
It is a walled yard of 12 x 10 m with a chamfered corner, boxes with sharp edges (some turned), poles, a ramp and a
step (planes that are not axis-aligned), and the calibration board of
:data:`~backend.sim.demo_rig.DEMO_BOARD` (the printed pattern plus its white margin,
as :func:`~backend.sim.board_renderer.plate_corners_m`) on a post about 2.6 m ahead,
where both cameras and both LiDARs see it. Planes in every orientation and edges
make LiDAR-to-LiDAR registration well conditioned; the board, seen by the cameras
and the LiDARs, serves LiDAR-to-camera calibration.

The board frame is the one of :class:`~backend.core.boards.BoardSpec` (origin at the
first inner corner, x along the columns, y along the rows, z into the board); the
print is the plate face at board z = 0, the face the cameras see.

:class:`LidarScene` casts rays with Open3D's ``RaycastingScene`` (imported lazily):
:meth:`LidarScene.scan_3d` is a VLP-16-like spinning scan and :meth:`LidarScene.scan_2d`
a 360 deg planar scan. Every scan returns noisy points in the sensor frame and the
noise-free hit points, so tests and solvers can compare against ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from backend.core.boards import BoardSpec
from backend.core.transforms import R_BODY_OPTICAL, from_xyz_ypr, make_T, transform_points
from backend.devices.base import DeviceError
from backend.sim.board_renderer import plate_corners_m
from backend.sim.demo_rig import DEMO_BOARD

LABELS: dict[str, int] = {"floor": 1, "wall": 2, "box": 3, "pole": 4, "ramp": 5, "board": 6, "stand": 7}
"""Surface label of each triangle (and of each LiDAR return); 0 means no surface."""

REFLECTIVITY: dict[int, float] = {1: 25.0, 2: 50.0, 3: 80.0, 4: 110.0, 5: 40.0, 6: 230.0, 7: 35.0}
"""Intensity of a return at normal incidence, per label (0..255, like a VLP-16). For the
board this is the white paper; its black squares return :data:`BOARD_INK_INTENSITY`."""
_REFLECTIVITY_BY_LABEL = np.array([0.0, *(REFLECTIVITY[i] for i in range(1, len(REFLECTIVITY) + 1))])


def label_reflectivity(labels: np.ndarray) -> np.ndarray:
    """Intensity at normal incidence (0..255, :data:`REFLECTIVITY`) of returns with ``labels``; 0 for label 0."""
    return _REFLECTIVITY_BY_LABEL[np.asarray(labels)]


BOARD_INK_INTENSITY = 70.0
"""Intensity of a return from a black square of the board at normal incidence (still brighter than anything else)."""

ROOM_X_M = (-4.0, 8.0)
"""x (m, base_link) of the inner faces of the back and front walls."""
ROOM_Y_M = (-5.0, 5.0)
"""y (m, base_link) of the inner faces of the right and left walls."""
WALL_HEIGHT_M = 3.0
"""Height of the walls (m); upward beams in the far corners pass over them (no return)."""
BOARD_THICKNESS_M = 0.006
"""Thickness of the board plate (m), behind the print (board z from 0 to this)."""

DEFAULT_BOARD = {"distance_m": 2.6, "lateral_m": 0.1, "height_m": 0.28, "yaw_deg": 12.0, "pitch_deg": 6.0,
                 "roll_deg": 3.0}
"""Settings of :func:`board_pose` for the static board: the plate crosses the 2D scanner's
plane, spans four rings of the 3D LiDAR, and is fully inside both camera images."""


# --- mesh building -------------------------------------------------------------------------------------------------

def _box(T_base_box: np.ndarray, size_m: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A box of ``size_m`` (m) with its bottom face centred at the origin of ``T_base_box``."""
    sx, sy, sz = size_m
    corners = np.array([[x, y, z] for z in (0.0, sz) for y in (-sy / 2, sy / 2) for x in (-sx / 2, sx / 2)])
    # vertex index = 4 * iz + 2 * iy + ix; every face wound counter-clockwise seen from outside
    faces = np.array([
        [0, 2, 3], [0, 3, 1],  # bottom (z-)
        [4, 5, 7], [4, 7, 6],  # top (z+)
        [0, 1, 5], [0, 5, 4],  # y-
        [2, 6, 7], [2, 7, 3],  # y+
        [0, 4, 6], [0, 6, 2],  # x-
        [1, 3, 7], [1, 7, 5],  # x+
    ])
    return transform_points(T_base_box, corners), faces


def _plate(T_base_board: np.ndarray, corners_board: np.ndarray, thickness_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A plate whose front face is the quad ``corners_board`` (board z = 0), ``thickness_m`` deep along board z."""
    (x0, y0), (x1, y1) = corners_board[:, :2].min(axis=0), corners_board[:, :2].max(axis=0)
    T_board_box = make_T(np.eye(3), [(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    vertices, faces = _box(T_board_box, (x1 - x0, y1 - y0, thickness_m))
    return transform_points(T_base_board, vertices), faces


def _cylinder(center_xy_m: tuple[float, float], radius_m: float, z0_m: float, z1_m: float,
              segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A vertical closed cylinder (m) in ``base_link``."""
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.column_stack([center_xy_m[0] + radius_m * np.cos(angles), center_xy_m[1] + radius_m * np.sin(angles)])
    bottom = np.column_stack([ring, np.full(segments, z0_m)])
    top = np.column_stack([ring, np.full(segments, z1_m)])
    centres = np.array([[*center_xy_m, z0_m], [*center_xy_m, z1_m]])
    vertices = np.vstack([bottom, top, centres])
    i = np.arange(segments)
    j = (i + 1) % segments
    cb, ct = 2 * segments, 2 * segments + 1
    faces = np.vstack([
        np.column_stack([i, j, j + segments]), np.column_stack([i, j + segments, i + segments]),  # side
        np.column_stack([np.full(segments, cb), j, i]),  # bottom cap
        np.column_stack([np.full(segments, ct), i + segments, j + segments]),  # top cap
    ])
    return vertices, faces


def _wedge(T_base_wedge: np.ndarray, length_m: float, width_m: float, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A ramp: rises from z = 0 at x = 0 to ``height_m`` at x = ``length_m``, ``width_m`` wide (m), centred on y = 0."""
    w = width_m / 2
    vertices = np.array([[0, -w, 0], [length_m, -w, 0], [length_m, -w, height_m],
                         [0, w, 0], [length_m, w, 0], [length_m, w, height_m]], dtype=float)
    faces = np.array([
        [0, 2, 1], [3, 4, 5],  # side triangles
        [0, 1, 4], [0, 4, 3],  # bottom
        [1, 2, 5], [1, 5, 4],  # back (vertical)
        [0, 3, 5], [0, 5, 2],  # slope
    ])
    return transform_points(T_base_wedge, vertices), faces


def _pose(x_m: float, y_m: float, z_m: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    return from_xyz_ypr(np.array([x_m, y_m, z_m]), np.radians([yaw_deg, 0.0, 0.0]))


def board_pose(distance_m: float, lateral_m: float, height_m: float, yaw_deg: float = 0.0, pitch_deg: float = 0.0,
               roll_deg: float = 0.0, board: str = DEMO_BOARD) -> np.ndarray:
    """``T_base_board`` of a board with its plate centre at (``distance_m``, ``lateral_m``, ``height_m``) (m, base).

    At zero angles the print faces the robot upright (board x to the robot's right,
    y down, z away from the robot). The plate is then turned by ROS yaw, pitch, roll
    (deg) about base_link axes through its centre: positive yaw turns it to face the
    robot's right-hand side, positive pitch leans it back so it faces upward.
    """
    spec = BoardSpec.parse(board)
    centre_board = plate_corners_m(spec).mean(axis=0)
    R = from_xyz_ypr(np.zeros(3), np.radians([yaw_deg, pitch_deg, roll_deg]))[:3, :3] @ R_BODY_OPTICAL
    return make_T(R, np.array([distance_m, lateral_m, height_m]) - R @ centre_board)


ROBOT_PLACES: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0), (0.6, -0.9, -20.0), (-0.6, 1.0, 25.0))
"""Where the simulated robot can stand in the yard: x, y (m) of ``base_link`` in the yard's frame and its heading
(deg). Place 0 is the yard's origin; from each place both LiDARs see walls, boxes and poles all round."""


def is_robot_place(place: object) -> bool:
    """Whether ``place`` is an index of :data:`ROBOT_PLACES`."""
    return isinstance(place, int) and 0 <= place < len(ROBOT_PLACES)


def robot_place(place: int, device: str = "simulated robot") -> np.ndarray:
    """``T_yard_base`` (4x4, m) of the robot standing at ``ROBOT_PLACES[place]``; :class:`DeviceError` naming
    ``device`` for a place that is not one of them."""
    if not is_robot_place(place):
        raise DeviceError(f"place must be one of 0-{len(ROBOT_PLACES) - 1} (where the robot can stand in the yard), "
                          f"not {place!r}", device)
    x_m, y_m, heading_deg = ROBOT_PLACES[place]
    return _pose(x_m, y_m, yaw_deg=heading_deg)


def default_board_pose() -> np.ndarray:
    """``T_base_board`` of the static board (:data:`DEFAULT_BOARD`)."""
    return board_pose(**DEFAULT_BOARD)


MIN_BOARD_TILT_DEG = 15.0
"""Least angle (deg) between a carried board's normal and the robot's forward axis: a board facing the camera
squarely from 2-3 m leaves its PnP rotation poorly determined (up to 0.6 deg off in the demo), which a
LiDAR-to-camera solve takes over as the board plane's tilt."""


def moving_board_poses(n: int, seed: int = 0, board: str = DEMO_BOARD) -> list[np.ndarray]:
    """``n`` deterministic ``T_base_board`` poses of a board carried about in front of the robot.

    The plate centre stays 1.8-3.2 m ahead and within 0.45 m of the centre line, turned by up to
    40 deg of yaw, leaning back by up to 30 deg (or forward by 10) and rolled by up to 35 deg, and
    always tilted at least :data:`MIN_BOARD_TILT_DEG` from facing the robot, so both cameras see it whole
    and its pose is well determined. The person holds it low (centre 0.22-0.34 m high, where the plate
    crosses the 2D scanner's plane) at even poses and at chest height (0.45-0.75 m, where more rings of
    the 3D LiDAR cross it) at odd ones: a LiDAR-to-camera solve needs the plate's edges on many scan
    lines and its normal turned every way. Pose 0 is the static :func:`default_board_pose`.
    """
    rng = np.random.default_rng([seed, 7321])
    poses = [board_pose(**DEFAULT_BOARD, board=board)]
    while len(poses) < n:
        height_m = (0.22, 0.34) if len(poses) % 2 == 0 else (0.45, 0.75)
        T = board_pose(rng.uniform(1.8, 3.2), rng.uniform(-0.45, 0.45), rng.uniform(*height_m),
                       rng.uniform(-40, 40), rng.uniform(-10, 30), rng.uniform(-35, 35), board=board)
        if T[0, 2] < np.cos(np.radians(MIN_BOARD_TILT_DEG)):  # board z (away from the robot) against base x
            poses.append(T)
    return poses[:n]


@lru_cache(maxsize=1)
def _static_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    parts: list[tuple[np.ndarray, np.ndarray, str]] = []
    (x0, x1), (y0, y1) = ROOM_X_M, ROOM_Y_M
    t = 0.2  # wall thickness (m)
    parts.append((*_box(_pose((x0 + x1) / 2, (y0 + y1) / 2, -0.1), (x1 - x0 + 2 * t, y1 - y0 + 2 * t, 0.1)), "floor"))
    parts.append((*_box(_pose(x0 - t / 2, (y0 + y1) / 2), (t, y1 - y0 + 2 * t, WALL_HEIGHT_M)), "wall"))
    parts.append((*_box(_pose(x1 + t / 2, (y0 + y1) / 2), (t, y1 - y0 + 2 * t, WALL_HEIGHT_M)), "wall"))
    parts.append((*_box(_pose((x0 + x1) / 2, y0 - t / 2), (x1 - x0 + 2 * t, t, WALL_HEIGHT_M)), "wall"))
    parts.append((*_box(_pose((x0 + x1) / 2, y1 + t / 2), (x1 - x0 + 2 * t, t, WALL_HEIGHT_M)), "wall"))
    # chamfered front-left corner: a wall at 45 deg whose inner face runs from (x1 - 2.5, y1) to (x1, y1 - 2.5)
    chamfer = 2.5 * np.sqrt(2)
    inner_mid = np.array([x1 - 1.25, y1 - 1.25])
    centre = inner_mid + t / 2 * np.array([1.0, 1.0]) / np.sqrt(2)
    parts.append((*_box(_pose(*centre, yaw_deg=-45.0), (t, chamfer + 0.4, WALL_HEIGHT_M)), "wall"))
    # boxes with sharp edges, some turned
    parts.append((*_box(_pose(5.0, -2.5), (1.0, 0.8, 0.9)), "box"))
    parts.append((*_box(_pose(5.05, -2.45, 0.9, yaw_deg=15.0), (0.6, 0.5, 0.5)), "box"))
    parts.append((*_box(_pose(3.6, 3.0, yaw_deg=30.0), (0.8, 0.8, 1.2)), "box"))
    parts.append((*_box(_pose(-2.5, -3.2, yaw_deg=-20.0), (1.2, 0.6, 0.7)), "box"))
    parts.append((*_box(_pose(6.8, 1.8, yaw_deg=-10.0), (0.5, 1.4, 1.6)), "box"))
    # poles
    for xy in [(2.0, -1.9), (4.6, 1.3), (-1.6, 2.4), (6.3, -0.6), (1.2, 2.2)]:
        parts.append((*_cylinder(xy, 0.06, 0.0, 2.5), "pole"))
    # a ramp rising towards the back-left, turned, and a low step on the right
    parts.append((*_wedge(_pose(-1.2, 3.2, yaw_deg=160.0), 2.0, 1.4, 0.5), "ramp"))
    parts.append((*_box(_pose(1.0, -3.8, yaw_deg=8.0), (1.6, 1.0, 0.2)), "ramp"))
    return _concat(parts)


def _concat(parts: list[tuple[np.ndarray, np.ndarray, str | np.ndarray]]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Join meshes; each part's label is a :data:`LABELS` name or an array of label values per triangle."""
    vertices, triangles, labels, offset = [], [], [], 0
    for v, f, label in parts:
        vertices.append(v)
        triangles.append(f + offset)
        labels.append(np.full(len(f), LABELS[label], np.int8) if isinstance(label, str) else label)
        offset += len(v)
    return np.vstack(vertices), np.vstack(triangles).astype(np.int64), np.concatenate(labels)


def scene_mesh(board_pose: np.ndarray | None = None, *, include_board: bool = True,
               board: str = DEMO_BOARD, include_yard: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scene as ``(vertices (V, 3) float64 m in base_link, triangles (T, 3) int64, labels (T,) int8)``.

    ``board_pose`` is ``T_base_board`` (default :func:`default_board_pose`); the board
    is a plate of ``board``'s printed size plus its white margin, on a post standing
    on the floor behind the plate's centre. Labels are values of :data:`LABELS`.
    Without ``include_yard`` the mesh is the board and its post alone.
    """
    parts: list[tuple[np.ndarray, np.ndarray, str | np.ndarray]] = [_static_mesh()] if include_yard else []
    if include_board:
        T = default_board_pose() if board_pose is None else np.asarray(board_pose, dtype=float)
        corners = plate_corners_m(BoardSpec.parse(board))
        parts.append((*_plate(T, corners, BOARD_THICKNESS_M), "board"))
        behind = transform_points(T, np.array([[*corners.mean(axis=0)[:2], BOARD_THICKNESS_M + 0.02]]))[0]
        if behind[2] > 0.01:
            parts.append((*_cylinder((behind[0], behind[1]), 0.015, 0.0, behind[2]), "stand"))
    return _concat(parts)


# --- ray casting ---------------------------------------------------------------------------------------------------

@dataclass
class LidarScan:
    """One simulated scan; row ``i`` of every array is one return."""

    points: np.ndarray
    """(N, 3) float64 measured points in the sensor frame (m), with range noise; z = 0 for a 2D scan."""
    intensity: np.ndarray
    """(N,) float32 return intensity (0..255)."""
    ring: np.ndarray
    """(N,) int16 beam index, 0 for the lowest beam (always 0 for a 2D scan)."""
    labels: np.ndarray
    """(N,) int8 surface label (:data:`LABELS`) of each return."""
    points_true: np.ndarray
    """(N, 3) float64 noise-free hit points in the sensor frame (m)."""
    azimuth_rad: np.ndarray
    """(N,) azimuth of each beam in the sensor frame (rad, from x towards y)."""
    T_base_sensor: np.ndarray
    """Ground-truth pose of the sensor in base_link (4x4, m)."""

    def __len__(self) -> int:
        return len(self.points)

    def points_base(self, true: bool = False) -> np.ndarray:
        """The (noisy, or with ``true`` noise-free) points mapped into base_link with the ground truth (m)."""
        return transform_points(self.T_base_sensor, self.points_true if true else self.points)


class LidarScene:
    """The scene of :func:`scene_mesh` in an Open3D ``RaycastingScene``, scanned by simulated LiDARs."""

    def __init__(self, board_pose: np.ndarray | None = None, *, include_board: bool = True, board: str = DEMO_BOARD,
                 include_yard: bool = True):
        import open3d as o3d

        self.board = BoardSpec.parse(board)
        self.T_base_board = default_board_pose() if board_pose is None else np.asarray(board_pose, float).copy()
        self.include_board = include_board
        self.vertices, self.triangles, self.labels = scene_mesh(self.T_base_board, include_board=include_board,
                                                                board=board, include_yard=include_yard)
        self._o3c = o3d.core
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(self.vertices.astype(np.float32)),
                                  o3d.core.Tensor(self.triangles.astype(np.uint32)))

    def cast(self, origin_base: np.ndarray, directions_base: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cast rays from one origin (3,) or one per ray (N, 3) (m) along unit directions (N, 3), all in base_link.

        Returns the hit distance (m, ``inf`` for no hit), the label (0 for no hit) and
        the unit surface normal of each ray.
        """
        rays = np.empty((len(directions_base), 6), np.float32)
        rays[:, :3] = origin_base
        rays[:, 3:] = directions_base
        result = self._scene.cast_rays(self._o3c.Tensor(rays))
        t = result["t_hit"].numpy().astype(np.float64)
        ids = result["primitive_ids"].numpy()
        hit = np.isfinite(t)
        labels = np.zeros(len(t), np.int8)
        labels[hit] = self.labels[ids[hit]]
        return t, labels, result["primitive_normals"].numpy().astype(np.float64)

    def distance_to_mesh(self, points_base: np.ndarray) -> np.ndarray:
        """Unsigned distance (m) of each base_link point (N, 3) to the nearest triangle."""
        query = self._o3c.Tensor(np.asarray(points_base, np.float32).reshape(-1, 3))
        return self._scene.compute_distance(query).numpy().astype(np.float64)

    def _scan(self, T_base_sensor: np.ndarray, dirs_sensor: np.ndarray, ring: np.ndarray, azimuth: np.ndarray,
              max_range_m: float, range_noise_m: float, rng: np.random.Generator) -> LidarScan:
        T = np.asarray(T_base_sensor, dtype=float)
        dirs_base = dirs_sensor @ T[:3, :3].T
        t, labels, normals = self.cast(T[:3, 3], dirs_base)
        keep = np.isfinite(t) & (t <= max_range_m)
        noise = rng.normal(0.0, range_noise_m, len(t)) if range_noise_m > 0 else np.zeros(len(t))
        t, labels, normals, noise = t[keep], labels[keep], normals[keep], noise[keep]
        dirs = dirs_sensor[keep]
        points_true = dirs * t[:, None]
        points = dirs * (t + noise)[:, None]
        cos_incidence = np.abs(np.einsum("ij,ij->i", normals, dirs_base[keep]))
        reflect = label_reflectivity(labels)
        on_board = labels == LABELS["board"]
        if on_board.any():
            hits_board = transform_points(np.linalg.solve(self.T_base_board, T), points_true[on_board])
            reflect[np.flatnonzero(on_board)[self.on_black_square(hits_board)]] = BOARD_INK_INTENSITY
        intensity = reflect * (0.35 + 0.65 * cos_incidence) + rng.normal(0.0, 1.5, len(t))
        return LidarScan(points=points, intensity=np.clip(intensity, 0, 255).astype(np.float32),
                         ring=ring[keep].astype(np.int16), labels=labels, points_true=points_true,
                         azimuth_rad=azimuth[keep], T_base_sensor=T.copy())

    def on_black_square(self, points_board: np.ndarray) -> np.ndarray:
        """Whether board-frame points (m) on the print fall on a black square (as :meth:`BoardSpec.render`)."""
        sq = self.board.square_m
        ix = np.floor((points_board[:, 0] + sq) / sq).astype(int)
        iy = np.floor((points_board[:, 1] + sq) / sq).astype(int)
        n_x, n_y = round(self.board.size_m[0] / sq), round(self.board.size_m[1] / sq)
        inside = (ix >= 0) & (ix < n_x) & (iy >= 0) & (iy < n_y) & (points_board[:, 2] < 1e-3)
        return inside & ((ix + iy) % 2 == 0)

    def scan_3d(self, T_base_lidar: np.ndarray, *, beams: int = 16, vertical_fov_deg: tuple[float, float] = (-15, 15),
                azimuth_step_deg: float = 0.2, max_range_m: float = 100.0, range_noise_m: float = 0.01,
                rng: np.random.Generator | int | None = None) -> LidarScan:
        """One revolution of a spinning multi-beam LiDAR (VLP-16-like by default) at ``T_base_lidar``.

        ``beams`` beams are evenly spaced over ``vertical_fov_deg`` (deg, elevation from
        the sensor's x-y plane, ring 0 lowest); columns every ``azimuth_step_deg``
        (deg) around the sensor's z axis, starting at a random phase below one step.
        Returns hit within ``max_range_m`` (m), ranges with Gaussian noise
        ``range_noise_m`` (m, 1-sigma), ordered column by column.
        """
        rng = np.random.default_rng(rng)
        elevation = np.radians(np.linspace(vertical_fov_deg[0], vertical_fov_deg[1], beams))
        n_cols = int(round(360.0 / azimuth_step_deg))
        azimuth = np.radians(rng.uniform(0.0, azimuth_step_deg) + azimuth_step_deg * np.arange(n_cols))
        az, el = np.meshgrid(azimuth, elevation, indexing="ij")
        dirs = np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(),
                                np.sin(el).ravel()])
        ring = np.tile(np.arange(beams), n_cols)
        return self._scan(T_base_lidar, dirs, ring, az.ravel(), max_range_m, range_noise_m, rng)

    def scan_2d(self, T_base_scanner: np.ndarray, *, angle_step_deg: float = 0.25, max_range_m: float = 30.0,
                range_noise_m: float = 0.01, rng: np.random.Generator | int | None = None) -> LidarScan:
        """One 360 deg sweep of a planar scanner at ``T_base_scanner``, in its x-y plane (points have z = 0).

        Beams every ``angle_step_deg`` (deg) from the sensor's x axis towards y, hits
        within ``max_range_m`` (m), Gaussian range noise ``range_noise_m`` (m, 1-sigma).
        """
        rng = np.random.default_rng(rng)
        azimuth = np.radians(angle_step_deg * np.arange(int(round(360.0 / angle_step_deg))))
        dirs = np.column_stack([np.cos(azimuth), np.sin(azimuth), np.zeros(len(azimuth))])
        return self._scan(T_base_scanner, dirs, np.zeros(len(azimuth), int), azimuth, max_range_m, range_noise_m, rng)
