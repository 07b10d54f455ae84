"""The simulated demo rig: ground-truth intrinsics and mounting of every sensor.

The rig is rooted at ``base_link`` (x forward, y left, z up). Cameras are optical
frames (x right, y down, z forward) mounted near the front of the body; the LiDARs
are body-like frames (x forward, y left, z up). Everything here is ground truth the
demo and the tests compare calibration results against.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.rig import Frame, Rig
from backend.core.transforms import R_BODY_OPTICAL, from_xyz_ypr, make_T
from backend.sim.tape_measure import tape_guess

DEMO_BOARD = "checkerboard:9x6:0.04"
DEMO_LIDAR_CLOCK_OFFSET_S = 0.035
"""How far (s) ``lidar_top``'s clock runs ahead of the cameras': the offset step 11 measures (``t_lidar = t_camera +
offset``)."""
"""The board spec the demo and the simulated cameras use by default."""



def _intrinsics(fx: float, fy: float, cx: float, cy: float, dist: list[float]) -> CameraIntrinsics:
    """A 1280x720 ``pinhole-radtan`` camera; focal lengths and centre in px."""
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return CameraIntrinsics("pinhole-radtan", 1280, 720, K, np.array(dist))


def _mount(xyz_m: tuple[float, float, float], ypr_deg: tuple[float, float, float], optical: bool) -> np.ndarray:
    """``T_base_sensor`` for a sensor at ``xyz_m`` (m) turned by ROS yaw, pitch, roll (deg) in the body frame.

    With ``optical`` the sensor frame is an optical frame whose z axis points along
    the turned body x axis (so zero angles look straight ahead).
    """
    T = from_xyz_ypr(np.array(xyz_m), np.radians(ypr_deg))
    if optical:
        T[:3, :3] = T[:3, :3] @ R_BODY_OPTICAL
    return T


CAM_FRONT = _intrinsics(902.5, 899.0, 645.3, 357.8, [-0.12, 0.05, 0.0008, -0.0005, 0.0])
"""Narrow front camera with mild barrel distortion."""

CAM_RIGHT = _intrinsics(898.0, 896.6, 640.8, 361.2, [-0.11, 0.045, -0.0004, 0.0006, 0.0])
"""The front camera's stereo partner, 12 cm to its right: the same lens family, its own small differences."""

CAM_WIDE = _intrinsics(520.0, 519.2, 637.6, 362.9, [-0.25, 0.0925, 0.0003, 0.0004, -0.0115])
"""Wide camera with strong barrel distortion (about 116 deg horizontal field of view).

The radial polynomial is chosen so its slope falls steadily out to the image
corners (where the image is compressed to about 0.64 of the pinhole scale) and the
map does not fold over until 6 % beyond them. With ``k1 = -0.30, k2 = 0.09,
k3 = -0.01`` at this focal length it folds before the image corners, so those
pixels would have no ray at all.
"""


SWEEP_NOMINAL_GEOMETRY: dict = {
    "axis": [1.0, 0.0, 0.0],
    "T_servo_scanner": make_T(np.eye(3), np.array([0.03, 0.0, 0.05])).tolist(),
    "zero_offset_rad": 0.0,
}
"""The swept scanner's geometry as drawn (:class:`~backend.core.sweep_geometry.SweepGeometry` dict): servo axis
along mount x, optical centre 3 cm along it and 5 cm above, no tilt, servo zero as read. The truth
(:data:`DEFAULT_SIM_GEOMETRY`) is off by about a centimetre and 1.5 deg."""

DEFAULT_SIM_GEOMETRY: dict[str, Any] = {
    "axis": [1.0, 0.0, 0.0],
    "T_servo_scanner": from_xyz_ypr(np.array([0.03, 0.012, 0.045]), np.radians([0.6, -0.8, 0.0])).tolist(),
    "zero_offset_rad": math.radians(1.5),
}
"""The TRUE geometry of the simulated swept scanner (:class:`~backend.sim.swept_head.SimSweptScannerHead`): the
optical centre 3 cm along the axis, 1.2 cm beside and 4.5 cm above it, turned by 0.6 deg yaw and -0.8 deg pitch;
the servo's zero reads 1.5 deg off."""
DEFAULT_SIM_MOUNT: list[list[float]] = from_xyz_ypr(np.array([0.35, 0.0, 0.75]), np.zeros(3)).tolist()
"""``T_base_mount`` of the simulated swept scanner (the ``sweep_3d`` frame): level, 35 cm ahead of base_link and
75 cm up."""


def demo_rig() -> Rig:
    """A fresh copy of the ground-truth demo rig.

    Sensors: ``cam_front`` and ``cam_wide`` (cameras, 15 cm apart, a few degrees of
    relative rotation, driven by the ``simulated`` capture driver), ``cam_right`` (the front
    camera's stereo partner, 12 cm to its right), ``lidar_top``
    (3D spinning LiDAR on the roof), ``lidar_front`` (a second 3D LiDAR on the front,
    pitched down), ``scanner_2d`` (2D scanner low at the front), all driven by the ``simulated_lidar``
    driver (scans of :mod:`backend.sim.lidar_scene`), and ``sweep_3d``: a 2D scanner swept into 3D by
    a simulated Dynamixel (``swept_scanner`` driver; its frame is the servo's mount, at the simulator's
    truth), carrying the nominal :data:`SWEEP_NOMINAL_GEOMETRY` to calibrate.
    """
    rig = Rig("base_link")
    cameras = {
        "cam_front": (CAM_FRONT, (0.32, 0.06, 0.48), (1.5, 2.0, -0.8)),
        "cam_wide": (CAM_WIDE, (0.30, -0.09, 0.46), (-6.0, 4.5, 1.2)),
        "cam_right": (CAM_RIGHT, (0.32, -0.06, 0.48), (0.8, 1.6, -0.5)),
    }
    for name, (intrinsics, xyz_m, ypr_deg) in cameras.items():
        rig.add(
            Frame(
                name,
                "base_link",
                _mount(xyz_m, ypr_deg, optical=True),
                kind="camera",
                intrinsics=CameraIntrinsics.from_dict(intrinsics.to_dict()),
                device={"driver": "simulated", "camera": name, "seed": 0},
            )
        )
    T_base_lidar = _mount((0.05, 0.0, 0.82), (2.5, -0.6, 0.4), optical=False)
    rig.add(Frame("lidar_top", "base_link", T_base_lidar, kind="lidar3d",
                  device={"driver": "simulated_lidar", "sensor": "lidar_top", "seed": 0,
                          "clock_offset_s": DEMO_LIDAR_CLOCK_OFFSET_S}))
    T_base_front = _mount((0.42, -0.05, 0.55), (-3.0, 6.0, 1.2), optical=False)  # pitched down, like a Livox
    rig.add(Frame("lidar_front", "base_link", T_base_front, kind="lidar3d",
                  device={"driver": "simulated_lidar", "sensor": "lidar_front", "seed": 0}))
    T_base_scanner = _mount((0.38, 0.01, 0.18), (-1.0, 0.8, -0.3), optical=False)
    rig.add(Frame("scanner_2d", "base_link", T_base_scanner, kind="lidar2d",
                  device={"driver": "simulated_lidar", "sensor": "scanner_2d", "seed": 0}))
    rig.add(Frame("sweep_3d", "base_link", np.array(DEFAULT_SIM_MOUNT), kind="lidar3d",
                  device={"driver": "swept_scanner", "servo_port": "sim", "scanner": {"driver": "sim"},
                          "geometry": copy.deepcopy(SWEEP_NOMINAL_GEOMETRY)}))
    return rig


CAD_SENSORS = ("lidar_top", "sweep_3d")
"""Sensors whose mounting the demo takes from the robot's drawing, exact: ``lidar_top`` defines the body frame
(as the main LiDAR often does), ``sweep_3d`` is the servo's machined mount."""
CAD_SIGMA = (0.001, 0.05)
"""1-sigma of a drawing's mounting (m, deg per axis)."""
TAPE_ERROR_M = (0.02, 0.05)
"""How far (m, range of the norm) a tape-measured mounting is from the truth."""
TAPE_ERROR_DEG = (1.0, 3.0)
"""How far (deg, range of the angle) a protractor's mounting is turned from the truth."""
TAPE_SEED = 7


def measured_demo_rig(seed: int = TAPE_SEED) -> Rig:
    """The demo rig as a user first types it in (mounting guess and transform alike): the :data:`CAD_SENSORS` at
    the truth with :data:`CAD_SIGMA`, every other sensor tape-measured (:func:`~backend.sim.tape_measure.tape_guess`
    with :data:`TAPE_ERROR_M` and :data:`TAPE_ERROR_DEG`, seeded) with the default mounting sigma."""
    rng = np.random.default_rng(seed)
    rig = demo_rig()
    for frame in rig.sensors():
        if frame.name in CAD_SENSORS:
            frame.mount_sigma = CAD_SIGMA
        else:
            guess = tape_guess(frame.T_parent_child, rng, TAPE_ERROR_M, TAPE_ERROR_DEG)
            frame.T_parent_child, frame.T_mount = guess, guess.copy()
    return rig
