"""A LiDAR of the simulated demo rig scanning the simulated yard.

Scans are ray-cast from ground truth (:mod:`backend.sim.lidar_scene`): the sensor's
true pose ``T_base_sensor`` in :func:`backend.sim.demo_rig.demo_rig`, the place where the robot
stands in the yard, and the scene with the calibration board, either standing still or carried
through a cycle of poses in front of the robot. A ``lidar3d`` sensor gives a VLP-16-like 16-beam
spinning scan, a ``lidar2d`` sensor a 360 deg planar scan (points with z = 0).

The driver is ``"simulated_lidar"``, registered with :func:`~backend.devices.base.create_device` by
:mod:`backend.sim.devices`.
"""

from __future__ import annotations

import time

import numpy as np

from backend.devices.base import CaptureDevice, DeviceError, Sample
from backend.sim.carried_board import yard_board_pose
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_scene import LidarScan, LidarScene, default_board_pose, moving_board_poses, robot_place
from backend.sim.timing import SimulatedTiming


class SimulatedLidar(CaptureDevice):
    """Simulated scans of a demo-rig LiDAR; ``points`` in the sensor frame (m), ``intensity`` float32 (0..255).

    Sample ``i`` sees board pose ``i % board_poses`` (or the static board; with ``board_hold_s``
    the pose held at the moment of the read) and its noise and spin phase come from
    ``(seed, i)``, so a sample is the same whatever was read before it. ``meta`` holds
    ``frame_index``, ``board_pose_index``, ``sensor``, ``kind``, ``simulated: True``, the
    ground-truth ``T_base_sensor`` and ``T_base_board`` (4x4 nested lists, metres, into ``base_link``).
    """

    driver = "simulated_lidar"

    def __init__(
        self,
        sensor: str = "lidar_top",
        seed: int = 0,
        rate_hz: float = 0,
        board_poses: int = 0,
        board_hold_s: float = 0,
        board_carry_s: float = 0,
        clock_offset_s: float = 0,
        disconnect_after: int | None = None,
        place: int = 0,
    ):
        """Settings as stored in the rig.

        Args:
            sensor: name of a ``lidar3d`` or ``lidar2d`` sensor in the demo rig.
            seed: seeds the range noise, the spin phase and the board motion.
            rate_hz: scan rate to emulate (Hz); 0 scans as fast as possible.
            board_poses: if above 0, the board moves through a cycle of this many poses
                (:func:`~backend.sim.lidar_scene.moving_board_poses`); else it stands still.
            board_hold_s: if above 0, each pose is held for this many seconds of wall-clock time,
                the clock every simulated device shares (a simulated camera with
                ``board_motion="scene"`` and the same ``seed`` then sees the same board);
                else the pose advances with every scan.
            board_carry_s: if above 0 (with ``board_poses``), the board is carried on from each pose to the next in
                this many seconds of wall-clock time, without a jump (after ``board_hold_s`` there;
                :func:`~backend.sim.carried_board.carried_board_pose`), as a camera with the same setting sees it.
            clock_offset_s: the LiDAR's clock runs this far (s) ahead of the wall clock: every stamp has it added.
            disconnect_after: if set, reads after this many samples raise
                :class:`DeviceDisconnected`, to exercise capture robustness.
            place: where the robot stands in the yard (an index of
                :data:`~backend.sim.lidar_scene.ROBOT_PLACES`); the board is carried about in front of it.
        """
        self.sensor = sensor
        self.seed = seed
        self.board_poses = board_poses
        self.board_hold_s = board_hold_s
        self.board_carry_s = board_carry_s
        self.clock_offset_s = clock_offset_s
        self.place = place
        self._T_yard_base = np.eye(4)
        self._timing = SimulatedTiming(rate_hz, disconnect_after, "scans")
        self._kind: str | None = None
        self._T_base_sensor: np.ndarray | None = None
        self._poses: list[np.ndarray] = []
        self._scenes: dict[int, LidarScene] = {}

    def open(self) -> None:
        """Look the sensor up in the demo rig and plan the board's poses."""
        rig = demo_rig()
        frame = rig.frames.get(self.sensor)
        if frame is None or frame.kind not in ("lidar3d", "lidar2d"):
            lidars = [f.name for f in rig.sensors() if f.kind in ("lidar3d", "lidar2d")]
            raise DeviceError(f"no simulated LiDAR named {self.sensor!r}; available: {lidars}", self.describe())
        if self.board_poses < 0:
            raise DeviceError(f"board_poses must be 0 (static board) or more, not {self.board_poses}",
                              self.describe())
        if self.board_carry_s < 0 or (self.board_carry_s > 0 and self.board_poses == 0):
            raise DeviceError(f"board_carry_s must be 0, or above 0 with board_poses, not {self.board_carry_s} with "
                              f"{self.board_poses} board poses", self.describe())
        if self._timing.rate_hz < 0:
            raise DeviceError(f"rate_hz must be 0 or more, not {self._timing.rate_hz}", self.describe())
        self._T_yard_base = robot_place(self.place, self.describe())
        self._kind = frame.kind
        self._T_base_sensor = rig.T_root_frame(self.sensor)
        self._poses = moving_board_poses(self.board_poses, self.seed) if self.board_poses > 0 else [
            default_board_pose()]
        self._scenes = {}
        self._timing.restart()

    def scan(self, index: int, pose_index: int | None = None, T_base_board: np.ndarray | None = None) -> LidarScan:
        """The full simulated scan of sample ``index`` (rings, labels and noise-free points included), seeing
        board pose ``pose_index`` (default ``index`` modulo the poses), or the board at ``T_base_board`` (a carried
        board's pose between them: its scene is built for this scan alone)."""
        if self._T_base_sensor is None:
            raise DeviceError("scan() before open()", self.describe())
        if T_base_board is not None:
            scene = LidarScene(self._T_yard_base @ T_base_board)
        else:
            pose_index = index % len(self._poses) if pose_index is None else pose_index
            scene = self._scenes.get(pose_index)
            if scene is None:
                scene = self._scenes[pose_index] = LidarScene(self._T_yard_base @ self._poses[pose_index])
        rng = np.random.default_rng([self.seed, index])
        T_yard_sensor = self._T_yard_base @ self._T_base_sensor
        if self._kind == "lidar3d":
            return scene.scan_3d(T_yard_sensor, rng=rng)
        return scene.scan_2d(T_yard_sensor, rng=rng)

    def read(self) -> Sample:
        """Scan once more; raise :class:`DeviceDisconnected` once ``disconnect_after`` scans were read."""
        if self._T_base_sensor is None:
            raise DeviceError("read() before open()", self.describe())
        index = self._timing.next_frame(self.describe())
        scanned_s = time.time()
        pose_index, T_base_board = yard_board_pose(self._poses, index, scanned_s, self.board_hold_s,
                                                   self.board_carry_s)
        # a held pose's scene is cached; a carried board's stands where it is for this scan alone
        scan = self.scan(index, T_base_board=T_base_board) if self.board_carry_s > 0 else self.scan(index, pose_index)
        meta = {
            "frame_index": index,
            "board_pose_index": pose_index,
            "sensor": self.sensor,
            "kind": self._kind,
            "simulated": True,
            "T_base_sensor": self._T_base_sensor.tolist(),
            "T_base_board": T_base_board.tolist(),
            "place": self.place,
        }
        return Sample(scanned_s + self.clock_offset_s, points=scan.points, intensity=scan.intensity, meta=meta)

    def close(self) -> None:
        """Forget the scene; safe to call twice."""
        self._T_base_sensor = None
        self._kind = None
        self._poses = []
        self._scenes = {}

    def describe(self) -> str:
        if self._kind is None:
            return f"simulated_lidar {self.sensor}"
        return f"simulated_lidar {self.sensor} ({self._kind})"
