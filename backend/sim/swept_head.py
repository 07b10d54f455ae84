"""The simulated swept scanner: a ray-cast 2D scanner bolted to the simulated Dynamixel's horn.

``swept_scanner`` with ``servo_port="sim"`` starts the simulator registered as ``"dynamixel"`` (a
:class:`~backend.sim.dynamixel_sim.DynamixelSimulator`: byte-level Protocol 2.0 on a pty) and, with
``scanner={"driver": "sim", ...}``, the one registered as ``"swept_head"``: a :class:`SimSweptScannerHead` on that
simulator's horn. Each scan is ray-cast in :class:`~backend.sim.lidar_scene.LidarScene` from the pose the horn's
physical angle and the TRUE geometry (:data:`~backend.sim.demo_rig.DEFAULT_SIM_GEOMETRY`) give, so tests know
the truth. Both are registered by :mod:`backend.sim.devices`.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from backend.core.sweep_geometry import SweepGeometry
from backend.devices.base import CaptureDevice, DeviceDisconnected, Sample
from backend.sim.demo_rig import DEFAULT_SIM_GEOMETRY, DEFAULT_SIM_MOUNT, DEMO_BOARD
from backend.sim.dynamixel_sim import DynamixelSimulator
from backend.sim.lidar_scene import LidarScan, LidarScene, default_board_pose, robot_place


class SimSweptScannerHead(CaptureDevice):
    """A 2D scanner on the simulated servo's horn (``scanner={"driver": "sim", ...}``); not a registered driver.

    Each :meth:`read` ray-casts one planar scan (:meth:`LidarScene.scan_2d`) from
    ``T_base_mount @ geometry.T_mount_scanner(physical servo angle)`` with the TRUE geometry,
    keeps beams within ``fov_deg`` (a Hokuyo UTM-30LX sees 270 deg) and returns them in the
    scanner frame with intensity (0..255) and ``meta["T_base_scanner"]`` (truth).
    """

    driver = "sim"

    def __init__(self, servo_sim: DynamixelSimulator, geometry: dict | None = None, T_base_mount: list | None = None,
                 angle_step_deg: float = 0.25, fov_deg: float = 270.0, range_noise_m: float = 0.01,
                 max_range_m: float = 30.0, seed: int = 0, place: int = 0, board: str = DEMO_BOARD,
                 board_pose: list | None = None):
        """Args:
        servo_sim: the :class:`~backend.sim.dynamixel_sim.DynamixelSimulator` whose horn carries it.
        geometry: the TRUE :class:`SweepGeometry` as a dict (default :data:`DEFAULT_SIM_GEOMETRY`).
        T_base_mount: 4x4 (m) of the mount in the yard's base_link (default :data:`DEFAULT_SIM_MOUNT`).
        angle_step_deg: beam spacing (deg). fov_deg: field of view centred on scanner x (deg).
        range_noise_m: 1-sigma range noise (m). max_range_m: farthest return (m).
        seed: seeds the noise (scan ``i`` uses ``(seed, i)``).
        place: where the robot stands in the yard (an index of :data:`~backend.sim.lidar_scene.ROBOT_PLACES`).
        board: the spec of the board standing in the yard.
        board_pose: its ``T_base_board`` (4x4, m, in the robot's base_link; default the yard's static board,
            :func:`~backend.sim.lidar_scene.default_board_pose`).
        """
        self.servo_sim = servo_sim
        self.geometry = SweepGeometry.from_dict(DEFAULT_SIM_GEOMETRY if geometry is None else geometry)
        self.T_base_mount = np.asarray(DEFAULT_SIM_MOUNT if T_base_mount is None else T_base_mount, dtype=float)
        self.angle_step_deg = float(angle_step_deg)
        self.fov_deg = float(fov_deg)
        self.range_noise_m = float(range_noise_m)
        self.max_range_m = float(max_range_m)
        self.seed = int(seed)
        self.place = place
        self.board = board
        self.T_base_board = default_board_pose() if board_pose is None else np.asarray(board_pose, dtype=float)
        self._T_yard_base = np.eye(4)
        self._scene: LidarScene | None = None
        self._count = 0

    def ground_truth(self) -> dict[str, Any]:
        """What a sweep's ``meta`` carries as truth: ``true_geometry`` (dict) and ``T_base_mount`` (4x4 list, m)."""
        return {"true_geometry": self.geometry.to_dict(), "T_base_mount": self.T_base_mount.tolist()}

    def open(self) -> None:
        self._T_yard_base = robot_place(self.place, self.describe())
        self._scene = LidarScene(self._T_yard_base @ self.T_base_board, board=self.board)
        self._count = 0

    @property
    def scene(self) -> LidarScene | None:
        """The yard it scans (in the yard's frame), while open."""
        return self._scene

    def T_yard_scanner(self) -> np.ndarray:
        """The scanner's true pose in the yard now (4x4, m): the horn's physical angle through the TRUE geometry."""
        return self._T_yard_base @ self.T_base_mount @ self.geometry.T_mount_scanner(self.servo_sim.true_angle_rad())

    def read(self) -> Sample:
        if self._scene is None:
            raise DeviceDisconnected("read() before open()", self.describe())
        angle = self.servo_sim.true_angle_rad()
        T_base_scanner = self.T_base_mount @ self.geometry.T_mount_scanner(angle)
        scan = planar_scan(self._scene, self._T_yard_base @ T_base_scanner, self.angle_step_deg, self.fov_deg,
                           self.max_range_m, self.range_noise_m, np.random.default_rng([self.seed, self._count]))
        self._count += 1
        return Sample(time.time(), points=scan.points, intensity=scan.intensity,
                      meta={"T_base_scanner": T_base_scanner.tolist(), "true_servo_angle_rad": angle,
                            "labels": scan.labels})

    def close(self) -> None:
        self._scene = None

    def describe(self) -> str:
        return "simulated swept scanner head"


def planar_scan(scene: LidarScene, T_yard_scanner: np.ndarray, angle_step_deg: float, fov_deg: float,
                max_range_m: float, range_noise_m: float, rng: np.random.Generator) -> LidarScan:
    """One scan of a 2D scanner at ``T_yard_scanner`` (4x4, m), its beams every ``angle_step_deg`` within
    ``fov_deg`` centred on its x axis, in the scanner frame (:meth:`LidarScene.scan_2d`)."""
    scan = scene.scan_2d(T_yard_scanner, angle_step_deg=angle_step_deg, max_range_m=max_range_m,
                         range_noise_m=range_noise_m, rng=rng)
    azimuth = (scan.azimuth_rad + np.pi) % (2 * np.pi) - np.pi
    keep = np.abs(azimuth) <= math.radians(fov_deg) / 2 + 1e-9
    return LidarScan(**{name: value[keep] if isinstance(value, np.ndarray) and value.ndim and len(value) == len(keep)
                        else value for name, value in vars(scan).items()})


def static_sweep(scene: LidarScene, T_yard_mount: np.ndarray, geometry: SweepGeometry, servo_angles_rad: np.ndarray,
                 *, angle_step_deg: float = 0.25, fov_deg: float = 270.0, max_range_m: float = 30.0,
                 range_noise_m: float = 0.01, seed: int = 0) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """The raw scans ``(servo angle (rad), points (m, scanner frame), intensity)`` of one sweep through
    ``servo_angles_rad`` with the servo at each angle exactly, as :meth:`SweptScanner.scans_of` gives them, without
    the real-time servo: for tests and benchmarks that need many sweeps (the truth is ``geometry``)."""
    scans = []
    for k, angle in enumerate(np.asarray(servo_angles_rad, dtype=float)):
        scan = planar_scan(scene, T_yard_mount @ geometry.T_mount_scanner(float(angle)), angle_step_deg, fov_deg,
                           max_range_m, range_noise_m, np.random.default_rng([seed, k]))
        scans.append((float(angle), scan.points, scan.intensity))
    return scans
