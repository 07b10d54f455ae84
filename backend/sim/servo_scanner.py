"""The servo-scanner rig as simulated: a Hokuyo UTM-30LX-EW nodded by a Dynamixel servo, a camera on a pan head on top.

The rig's mount (the servo's housing, the swept scanner's frame) stands in the yard at the demo rig's
:data:`~backend.sim.demo_rig.DEFAULT_SIM_MOUNT`. The servo nods the scanner about the mount's y axis (left) in steps
of :data:`SERVO_STEP_DEG`, as the rig's Turret WidowX does (173 steps over 180 deg); the scanner sits on the horn
at :data:`NODDING`, the truth. The camera sits 12 cm above, looking ahead and a little down (:data:`T_MOUNT_CAMERA`,
its optical frame at pan reading 0), on a pan head that turns it about :data:`PAN_AXIS` through :data:`PAN_POINT`
(up, 0.6 deg off, 2 cm beside the camera) to the three positions of :data:`PAN_POSITIONS_DEG`.

The board is the rig's (:data:`BOARD`: 7 x 9 squares of 57 mm) held 0.65-0.9 m from the mount: six placements before
the camera at the centre (:data:`CENTRE_PLACEMENTS`) and four before each side (:data:`SIDE_PLACEMENTS`, turned with
the camera about the mount's vertical), what both the sweep and the camera there see. The camera's images are
photographs of the yard (:func:`~backend.sim.scene_camera.clean_yard_image`, the mesh the scanner ray-casts) with
sensor noise.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from backend.core.camera import CameraIntrinsics
from backend.core.sweep_geometry import SweepGeometry, SweepImage
from backend.core.transforms import R_BODY_OPTICAL, from_xyz_ypr, invert, make_T, rotation_about_line
from backend.sim.camera_device import SCENE_NOISE_SIGMA
from backend.sim.demo_rig import CAM_FRONT, DEFAULT_SIM_MOUNT
from backend.sim.lidar_scene import board_pose
from backend.sim.scene_camera import clean_yard_image

BOARD = "checkerboard:8x6:0.057"
"""The rig's board: 7 x 9 squares of 57 mm (6 x 8 inner corners)."""
SERVO_STEP_DEG = 1.05
"""The servo's step (deg): the Turret WidowX's 173 steps over 180 deg."""
NODDING = SweepGeometry(axis=np.array([0.0, 1.0, 0.0]), zero_offset_rad=math.radians(1.2),
                        T_servo_scanner=from_xyz_ypr(np.array([0.02, 0.01, 0.04]), np.radians([0.6, -0.8, 0.4])))
"""The TRUE sweep geometry: the servo nods the scanner about the mount's y axis (left); the scanner sits 2 cm ahead
of the axis and 4 cm above it, turned by under a degree; the servo's zero reads 1.2 deg off."""
T_BASE_MOUNT = np.array(DEFAULT_SIM_MOUNT)
"""``T_base_mount`` (4x4, m): level, 35 cm ahead of base_link and 75 cm up."""
T_MOUNT_CAMERA = from_xyz_ypr(np.array([0.02, -0.03, 0.12]), np.radians([1.5, 6.0, 0.5])) @ make_T(R_BODY_OPTICAL,
                                                                                                    np.zeros(3))
"""The camera at pan reading 0, 12 cm above the mount, looking ahead and a little down (its optical frame, m)."""
PAN_AXIS = Rotation.from_euler("xy", [0.5, -0.4], degrees=True).apply([0.0, 0.0, 1.0])
"""The pan head's true axis in the mount frame: up, 0.6 deg off."""
PAN_POINT = np.array([0.0, -0.01, 0.0])
"""A point of the true pan axis (m, mount frame): 2 cm beside the camera."""
PAN_POSITIONS_DEG = {"left": 45.0, "centre": 0.0, "right": -45.0}
"""The pan head's readings (deg) at the camera's three positions."""
CENTRE_PLACEMENTS = [(1.1, 0.05, 0.82, 10, 5, 3), (1.1, -0.1, 0.8, -15, -5, -4), (1.05, 0.0, 0.88, 5, 10, 8),
                     (1.12, 0.1, 0.78, 20, -10, 2), (1.0, -0.05, 0.84, -5, 0, -6), (1.22, 0.12, 0.8, 10, -5, 3)]
"""Board placements before the camera at pan 0: plate centres (m, base_link) and yaw, pitch, roll (deg) of
:func:`~backend.sim.lidar_scene.board_pose`, 0.65-0.9 m from the mount (the farthest whose squares still span
three servo steps) and turned every way: boards at one range leave the camera's yaw and its sideways offset
hardly told apart."""
SIDE_PLACEMENTS = [*CENTRE_PLACEMENTS[:3], (1.2, 0.0, 0.8, 0, -5, 0)]
"""Board placements before the camera at the sides, as before the centre (then turned with the camera)."""
SWEEP_START_DEG = -41.0
SWEEP_STEPS = 64
"""The part of the rig's sweep that holds the boards (-41..25 deg of its -90..90): the plates span -28..+16 deg of
servo reading straight ahead, and farther at the sides, where the nodding scan plane crosses them at a slant."""
CAMERA = CAM_FRONT
"""The camera's true intrinsics: 1280 x 720, fx 902 px, mild barrel distortion."""
YARD_TEXTURE_SEED = 0
"""Seeds the texture of the yard's surfaces, which is fixed to the scene."""


def T_mount_camera(pan_rad: float) -> np.ndarray:
    """The camera's true pose (4x4, m, optical frame) in the mount frame at pan reading ``pan_rad`` (rad)."""
    return rotation_about_line(PAN_AXIS, PAN_POINT, pan_rad) @ T_MOUNT_CAMERA


def board_placement(place: tuple, turn_rad: float = 0.0) -> np.ndarray:
    """``T_base_board`` (4x4, m) of a placement of :data:`CENTRE_PLACEMENTS` or :data:`SIDE_PLACEMENTS`, turned by
    ``turn_rad`` (rad) about the mount's vertical (before a camera panned that way)."""
    turn = make_T(Rotation.from_rotvec([0.0, 0.0, turn_rad]).as_matrix(), np.zeros(3))
    return T_BASE_MOUNT @ turn @ invert(T_BASE_MOUNT) @ board_pose(*place, board=BOARD)


def placements(position: str) -> list[np.ndarray]:
    """``T_base_board`` of each placement before the camera at ``position`` (a key of :data:`PAN_POSITIONS_DEG`):
    :data:`CENTRE_PLACEMENTS` or :data:`SIDE_PLACEMENTS` turned with the camera."""
    pan_rad = math.radians(PAN_POSITIONS_DEG[position])
    places = CENTRE_PLACEMENTS if pan_rad == 0.0 else SIDE_PLACEMENTS
    return [board_placement(place, pan_rad) for place in places]


def camera_image(T_base_board: np.ndarray, pan_rad: float, seed: int, camera: CameraIntrinsics = CAMERA
                 ) -> np.ndarray:
    """The camera's uint8 (H, W) photograph of the yard with the board at ``T_base_board`` (4x4, m), turned to pan
    reading ``pan_rad`` (rad), with the sensor noise of a simulated camera (seeded by ``seed``; the yard's texture
    is the same in every photograph)."""
    T_base_camera = T_BASE_MOUNT @ T_mount_camera(pan_rad)
    clean = clean_yard_image(T_base_board, BOARD, camera, T_base_camera, YARD_TEXTURE_SEED)
    noisy = clean + SCENE_NOISE_SIGMA * np.random.default_rng(seed).standard_normal(clean.shape, dtype=np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def sweep_angles_rad() -> np.ndarray:
    """The servo readings (rad) of the demo's sweeps: :data:`SWEEP_STEPS` steps of :data:`SERVO_STEP_DEG` from
    :data:`SWEEP_START_DEG`."""
    return np.radians(SWEEP_START_DEG + SERVO_STEP_DEG * np.arange(SWEEP_STEPS))


def true_image_px(points_mount: np.ndarray, image: SweepImage) -> np.ndarray:
    """(N, 2) column and row in a sweep's intensity ``image`` where the truly mounted scanner (:data:`NODDING`) sees
    each of (N, 3) mount-frame points (m): the servo reading whose scan plane holds the point, and the point's beam
    angle in it."""
    def in_scanner(point: np.ndarray, reading_rad: float) -> np.ndarray:
        return (invert(NODDING.T_mount_scanner(reading_rad)) @ np.r_[point, 1.0])[:3]

    rows = np.arange(len(image.servo_angles_rad))
    column_rad = (image.scan_angles_rad[-1] - image.scan_angles_rad[0]) / max(len(image.scan_angles_rad) - 1, 1)
    found = []
    for point in np.asarray(points_mount, dtype=float):
        reading = brentq(lambda angle, p=point: in_scanner(p, angle)[2], image.servo_angles_rad[0],
                         image.servo_angles_rad[-1])
        x, y, _ = in_scanner(point, reading)
        found.append([(math.atan2(y, x) - image.scan_angles_rad[0]) / column_rad,
                      np.interp(reading, image.servo_angles_rad, rows)])
    return np.array(found)
