"""A camera of the simulated demo rig filming a calibration board.

Frames are rendered from ground truth (:mod:`backend.sim`): the camera's true
intrinsics and mounting from :func:`backend.sim.demo_rig.demo_rig`, and the board
either waved in front of the camera for an intrinsic calibration
(:func:`backend.sim.board_motion.covering_poses`) or carried about the simulated yard,
where the simulated LiDARs see it too (:func:`backend.sim.lidar_scene.moving_board_poses`) and
the camera photographs the whole yard (:func:`backend.sim.scene_camera.clean_yard_image`), so
its edges line up with the LiDARs' points. Every sample carries the true ``T_camera_board``
in its metadata.

The driver is ``"simulated"``, registered with :func:`~backend.devices.base.create_device` by
:mod:`backend.sim.devices`.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np

from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, DeviceError, Sample
from backend.sim.board_motion import covering_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.carried_board import yard_board_pose
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import moving_board_poses, robot_place
from backend.sim.scene_camera import clean_yard_image
from backend.sim.timing import SimulatedTiming, held_pose_index

BOARD_MOTIONS = ("wave", "scene")
SCENE_NOISE_SIGMA = 1.5
"""Sensor noise (grey levels, 1-sigma) added to every frame of the yard."""


class SimulatedCamera(CaptureDevice):
    """Renders uint8 grayscale (H, W) images of a board seen by a demo-rig camera.

    Sample ``i`` shows pose ``i % n_poses`` of a deterministic sequence (with
    ``board_hold_s``, the pose held at the moment of the read) and its noise and
    lighting come from ``(seed, i)``, so a sample is the same whatever was read before
    it. ``meta`` holds ``frame_index``, ``board_pose_index``, the ground-truth
    ``T_camera_board`` (4x4 nested list, metres, board frame of :class:`BoardSpec` into
    the camera's optical frame) and ``simulated: True``; in the ``scene`` motion also
    ``T_base_board``.
    """

    driver = "simulated"

    def __init__(
        self,
        camera: str = "cam_front",
        seed: int = 0,
        board: str = DEMO_BOARD,
        n_poses: int = 150,
        fps: float = 0,
        disconnect_after: int | None = None,
        board_motion: str = "wave",
        board_hold_s: float = 0,
        board_carry_s: float = 0,
        clock_offset_s: float = 0,
        place: int = 0,
    ):
        """Settings as stored in the rig.

        Args:
            camera: name of a camera in the demo rig.
            seed: seeds the board motion and the image noise.
            board: board spec string of the target.
            n_poses: poses in the cycle the board moves through (the ``wave`` needs about 150 to reach every
                cell of the coverage heat map).
            fps: frame rate to emulate (Hz); 0 renders as fast as possible.
            disconnect_after: if set, reads after this many samples raise
                :class:`DeviceDisconnected`, to exercise capture robustness.
            board_motion: ``"wave"``: the board is waved close in front of the camera, all
                over the image and into its corners, as for an intrinsic calibration
                (:func:`~backend.sim.board_motion.covering_poses`, planned as it is shown); ``"scene"``: the board is
                carried about the simulated yard 2-3 m ahead of the robot, through the poses
                a ``simulated_lidar`` with ``board_poses=n_poses`` and the same ``seed`` sees
                (pose 0 is the yard's static board), for LiDAR-to-camera calibration.
            board_hold_s: if above 0, each pose is held for this many seconds of wall-clock
                time, the clock all simulated devices share; else the pose advances every frame.
            board_carry_s: in the ``scene`` motion, if above 0, the board is carried on from each pose to the next
                in this many seconds of wall-clock time, without a jump (after ``board_hold_s`` there;
                :func:`~backend.sim.carried_board.carried_board_pose`), as for lining clocks up.
            clock_offset_s: the camera's clock runs this far (s) ahead of the wall clock: every stamp has it added.
            place: where the robot stands in the yard in the ``scene`` motion (an index of
                :data:`~backend.sim.lidar_scene.ROBOT_PLACES`), as for a ``simulated_lidar``.
        """
        self.camera = camera
        self.seed = seed
        self.board = board
        self.n_poses = n_poses
        self.board_motion = board_motion
        self.board_hold_s = board_hold_s
        self.board_carry_s = board_carry_s
        self.clock_offset_s = clock_offset_s
        self.place = place
        self._T_yard_base = np.eye(4)
        self._timing = SimulatedTiming(fps, disconnect_after, "frames")
        self._intrinsics: CameraIntrinsics | None = None
        self._board_spec: BoardSpec | None = None
        self._poses: list[np.ndarray] = []
        self._planned: Iterator[np.ndarray] = iter(())
        self._T_base_boards: list[np.ndarray] | None = None
        self._T_base_camera: np.ndarray | None = None

    def open(self) -> None:
        """Look the camera up in the demo rig and plan the board motion."""
        frame = demo_rig().frames.get(self.camera)
        if frame is None or frame.intrinsics is None:
            cameras = [f.name for f in demo_rig().sensors("camera")]
            raise DeviceError(f"no simulated camera named {self.camera!r}; available: {cameras}", self.describe())
        try:
            board = BoardSpec.parse(self.board)
        except InputError as exc:
            raise DeviceError(exc.message, self.describe()) from None
        if self.n_poses < 1:
            raise DeviceError(f"n_poses must be at least 1, not {self.n_poses}", self.describe())
        if self.board_motion not in BOARD_MOTIONS:
            raise DeviceError(f"board_motion must be one of {', '.join(BOARD_MOTIONS)}, not {self.board_motion!r}",
                              self.describe())
        if self.board_carry_s < 0 or (self.board_carry_s > 0 and self.board_motion != "scene"):
            raise DeviceError(f"board_carry_s must be 0, or above 0 with board_motion 'scene', not "
                              f"{self.board_carry_s} with {self.board_motion!r}", self.describe())
        self._T_yard_base = robot_place(self.place, self.describe())
        self._intrinsics, self._board_spec = frame.intrinsics, board
        if self.board_motion == "wave":
            self._planned = covering_poses(frame.intrinsics, board, self.seed)
            self._poses = []
            self._T_base_boards = None
        else:
            self._T_base_camera = demo_rig().T_root_frame(self.camera)
            self._T_base_boards = moving_board_poses(self.n_poses, self.seed, board=self.board)
        self._timing.restart()

    def read(self) -> Sample:
        """Render the next frame; raise :class:`DeviceDisconnected` once ``disconnect_after`` frames were read."""
        if self._intrinsics is None or self._board_spec is None:
            raise DeviceError("read() before open()", self.describe())
        index = self._timing.next_frame(self.describe())
        exposed_s = time.time()  # the frame's stamp is its exposure, not the end of the render
        rng = np.random.default_rng([self.seed, index])
        if self._T_base_boards is None:
            pose_index = held_pose_index(index, self.n_poses, self.board_hold_s)
            while len(self._poses) <= pose_index:
                self._poses.append(next(self._planned))
            T_camera_board = self._poses[pose_index]
            image = render_board_image(self._intrinsics, self._board_spec, T_camera_board, rng)
            meta = {}
        else:
            pose_index, T_base_board = yard_board_pose(self._T_base_boards, index, exposed_s, self.board_hold_s,
                                                       self.board_carry_s)
            T_camera_board = np.linalg.inv(self._T_base_camera) @ T_base_board
            image = self._yard_image(T_base_board, rng)
            meta = {"T_base_board": T_base_board.tolist(), "place": self.place}
        meta = {"frame_index": index, "board_pose_index": pose_index, "T_camera_board": T_camera_board.tolist(),
                "simulated": True, **meta}
        return Sample(exposed_s + self.clock_offset_s, image=image, meta=meta)

    def _yard_image(self, T_base_board: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The yard with the board at ``T_base_board``, with fresh sensor noise from ``rng``."""
        clean = clean_yard_image(self._T_yard_base @ T_base_board, self.board, self._intrinsics,
                                 self._T_yard_base @ self._T_base_camera, self.seed)
        noisy = clean + SCENE_NOISE_SIGMA * rng.standard_normal(clean.shape, dtype=np.float32)
        return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)

    def close(self) -> None:
        """Forget the planned motion; safe to call twice."""
        self._intrinsics = None
        self._board_spec = None
        self._poses = []
        self._planned = iter(())
        self._T_base_boards = None

    def describe(self) -> str:
        if self._intrinsics is None:
            return f"simulated {self.camera}"
        return f"simulated {self.camera} {self._intrinsics.width}x{self._intrinsics.height}"
