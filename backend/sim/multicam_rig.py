"""A simulated ring of cameras watching a board carried around them, with ground truth.

The rig stands for the mining robot's camera cluster: cameras every
:data:`SPACING_DEG` around a vertical axis, looking outward, with different lenses and
resolutions (a narrow RGB camera, a stereo-like pair, a wide fisheye, a small thermal
camera). Neighbours overlap, cameras far apart never see the board together, so the
rig only connects through the cameras between them. The board walks around the ring
at 1.2-3 m; a camera observes it in a frame when the whole board is in its image and
faces it. Corners carry isotropic Gaussian noise (``noise_px``, 1-sigma per axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.calib.board.detection import Detection
from backend.calib.multicam.graph import Observation
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.transforms import from_xyz_ypr, invert, look_at, transform_points
from backend.sim.board_motion import plate_in_view

SPACING_DEG = 40.0
"""Default azimuth between neighbouring cameras (deg); each sees about 70 deg across, so neighbours overlap."""
RING_RADIUS_M = 0.25
MULTICAM_BOARD = BoardSpec.parse("checkerboard:9x6:0.08")
"""A large board (0.8 m x 0.56 m of corners), as one carries around a vehicle."""


def _pinhole(width: int, height: int, f: float, dist: list[float]) -> CameraIntrinsics:
    return CameraIntrinsics("pinhole-radtan", width, height,
                            np.array([[f, 0, width / 2 - 3.5], [0, f * 1.001, height / 2 + 2.5], [0, 0, 1]]), dist)


def _lenses(n: int) -> list[CameraIntrinsics]:
    lenses = [
        _pinhole(1280, 720, 900.0, [-0.12, 0.08, 0.0004, -0.0003, 0.0]),
        _pinhole(1920, 1200, 1350.0, [-0.08, 0.05, 0.0, 0.0, 0.0]),
        _pinhole(1920, 1200, 1340.0, [-0.081, 0.052, 0.0001, 0.0, 0.0]),
        CameraIntrinsics("fisheye-equidistant", 1280, 800,
                         np.array([[560.0, 0, 642.0], [0, 560.5, 398.0], [0, 0, 1]]), [0.05, -0.01, 0.002, -0.0005]),
        _pinhole(640, 512, 520.0, [-0.2, 0.1, 0.0, 0.0, 0.0]),
        _pinhole(848, 480, 610.0, [0.0, 0.0, 0.0, 0.0, 0.0]),
    ]
    return [lenses[i % len(lenses)] for i in range(n)]


@dataclass
class SimulatedMulticam:
    """Cameras (in order, the first the reference), their true poses and the board poses, all in the rig's frame."""

    cameras: dict[str, CameraIntrinsics]
    T_rig_cam: dict[str, np.ndarray]
    """4x4 (m): each camera's optical frame in the rig frame (x forward, y left, z up)."""
    T_rig_board: list[np.ndarray]
    board: BoardSpec

    def T_ref_cam(self, reference: str) -> dict[str, np.ndarray]:
        """True transforms from each camera's optical frame into ``reference``'s."""
        return {name: invert(self.T_rig_cam[reference]) @ T for name, T in self.T_rig_cam.items()}

    def observations(self, noise_px: float, seed: int) -> list[Observation]:
        """Every (camera, frame) in which the whole board is in view and faces the camera, with noisy corners."""
        rng = np.random.default_rng(seed)
        observations = []
        for index, T_rig_board in enumerate(self.T_rig_board):
            for name, camera in self.cameras.items():
                T_cam_board = invert(self.T_rig_cam[name]) @ T_rig_board
                faces = T_cam_board[:3, 2] @ T_cam_board[:3, 3] < 0  # board normal towards the camera
                if not faces or not plate_in_view(camera, self.board, T_cam_board, margin_px=5):
                    continue
                uv = camera.project(transform_points(T_cam_board, self.board.object_points.astype(float)))
                uv = uv + rng.normal(0.0, noise_px, uv.shape)
                detection = Detection(uv, np.arange(self.board.n_corners), camera.image_size)
                observations.append(Observation(name, f"{index:05d}", detection))
        return observations


def simulated_ring(n_cameras: int = 6, n_frames: int = 245, seed: int = 0, *, spacing_deg: float = SPACING_DEG,
                   walk_deg: float | None = None, board: BoardSpec = MULTICAM_BOARD) -> SimulatedMulticam:
    """``n_cameras`` around a ring (``cam0`` ... looking at azimuths 0, ``spacing_deg``, 2 ``spacing_deg`` ...),
    slightly off their nominal mounts, and ``n_frames`` board poses walking around them. A small spacing
    (3 deg) makes a forward-looking cluster; with a short ``walk_deg`` (the azimuths the board walks through,
    deg, centred on the cameras; default 50 deg beyond the outer cameras) every camera sees most frames."""
    rng = np.random.default_rng(seed)
    cameras, T_rig_cam = {}, {}
    for i, lens in enumerate(_lenses(n_cameras)):
        azimuth = np.radians(spacing_deg * i)
        eye = RING_RADIUS_M * np.array([np.cos(azimuth), np.sin(azimuth), 0.0]) + rng.normal(0, 0.01, 3)
        gaze = np.array([np.cos(azimuth), np.sin(azimuth), rng.normal(0, 0.05)])
        T_rig_optical = look_at(eye, eye + gaze, np.array([0.0, 0.0, 1.0]))
        T_rig_cam[f"cam{i}"] = T_rig_optical @ from_xyz_ypr(np.zeros(3), np.radians(rng.normal(0, 1.0, 3)))
        cameras[f"cam{i}"] = lens
    span = spacing_deg * (n_cameras - 1)
    walk_deg = span + 50 if walk_deg is None else walk_deg
    T_rig_board = []
    for k in range(n_frames):
        azimuth = np.radians((span - walk_deg) / 2 + walk_deg * (k + rng.uniform(-0.5, 0.5)) / n_frames)
        distance = rng.uniform(1.2, 3.0)
        centre = RING_RADIUS_M + distance
        position = np.array([centre * np.cos(azimuth), centre * np.sin(azimuth), rng.uniform(-0.3, 0.3)])
        # Board z axis (its normal) towards the ring's centre, tilted up to 35 deg, turned about its normal.
        T_face = look_at(position, np.array([0.0, 0.0, position[2]]) + rng.normal(0, 0.4, 3), np.array([0, 0, 1.0]))
        tilt = from_xyz_ypr(np.zeros(3), np.radians([rng.uniform(-180, 180), rng.uniform(-35, 35),
                                                     rng.uniform(-35, 35)]))
        centring = from_xyz_ypr(-np.append(board.object_points.mean(axis=0)[:2], 0.0), np.zeros(3))
        T_rig_board.append(T_face @ tilt @ centring)
    return SimulatedMulticam(cameras, T_rig_cam, T_rig_board, board)
