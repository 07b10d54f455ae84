"""A camera of the simulated demo rig filming a calibration board waved in front of it.

Frames are rendered from ground truth (:mod:`backend.sim`): the camera's true
intrinsics from :func:`backend.sim.demo_rig.demo_rig` and board poses from
:func:`backend.sim.board_motion.board_poses`, so every sample carries the true
``T_camera_board`` in its metadata.
"""

from __future__ import annotations

import time

import numpy as np

from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, DeviceError, Sample, register_driver
from backend.devices.simulated_timing import SimulatedTiming
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig


@register_driver
class SimulatedCamera(CaptureDevice):
    """Renders uint8 grayscale (H, W) images of a board seen by a demo-rig camera.

    Sample ``i`` shows pose ``i % n_poses`` of a deterministic sequence and its noise
    and lighting come from ``(seed, i)``, so a sample is the same whatever was read
    before it. ``meta`` holds ``frame_index``, the ground-truth ``T_camera_board``
    (4x4 nested list, metres, board frame of :class:`BoardSpec` into the camera's
    optical frame) and ``simulated: True``.
    """

    driver = "simulated"

    def __init__(
        self,
        camera: str = "cam_front",
        seed: int = 0,
        board: str = DEMO_BOARD,
        n_poses: int = 60,
        fps: float = 0,
        disconnect_after: int | None = None,
    ):
        """Settings as stored in the rig.

        Args:
            camera: name of a camera in the demo rig.
            seed: seeds the board motion and the image noise.
            board: board spec string of the target.
            n_poses: poses in the cycle the board moves through.
            fps: frame rate to emulate (Hz); 0 renders as fast as possible.
            disconnect_after: if set, reads after this many samples raise
                :class:`DeviceDisconnected`, to exercise capture robustness.
        """
        self.camera = camera
        self.seed = seed
        self.board = board
        self.n_poses = n_poses
        self._timing = SimulatedTiming(fps, disconnect_after, "frames")
        self._intrinsics: CameraIntrinsics | None = None
        self._board_spec: BoardSpec | None = None
        self._poses: list[np.ndarray] = []

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
        self._intrinsics, self._board_spec = frame.intrinsics, board
        self._poses = board_poses(frame.intrinsics, board, self.n_poses, self.seed)
        self._timing.restart()

    def read(self) -> Sample:
        """Render the next frame; raise :class:`DeviceDisconnected` once ``disconnect_after`` frames were read."""
        if self._intrinsics is None or self._board_spec is None:
            raise DeviceError("read() before open()", self.describe())
        index = self._timing.next_frame(self.describe())
        T_camera_board = self._poses[index % len(self._poses)]
        rng = np.random.default_rng([self.seed, index])
        image = render_board_image(self._intrinsics, self._board_spec, T_camera_board, rng)
        meta = {"frame_index": index, "T_camera_board": T_camera_board.tolist(), "simulated": True}
        return Sample(time.time(), image=image, meta=meta)

    def close(self) -> None:
        """Forget the planned motion; safe to call twice."""
        self._intrinsics = None
        self._board_spec = None
        self._poses = []

    def describe(self) -> str:
        if self._intrinsics is None:
            return f"simulated {self.camera}"
        return f"simulated {self.camera} {self._intrinsics.width}x{self._intrinsics.height}"
