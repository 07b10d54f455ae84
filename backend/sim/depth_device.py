"""A depth node of the simulated cell: a Kinect v2 class time-of-flight camera at its true pose.

Frames are rendered from ground truth (:mod:`backend.sim.depth_cell`): the node stands at its
pose in :data:`~backend.core.depth_cell.PAPER_NODE_POSES` in the cell of
:func:`~backend.core.depth_cell.default_cell_layout`, with the movable tables wherever the
last :meth:`SimulatedDepthCamera.set_placements` put them (none by default).

The driver is ``"sim_depth"``, registered with :func:`~backend.devices.base.create_device` by
:mod:`backend.sim.devices`.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from backend.core.depth import KINECT_V2
from backend.core.depth_cell import TablePlacement, default_cell_layout
from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, DeviceError, Sample
from backend.sim.depth_cell import CellScene, node_pose, placement_from_dict, placement_to_dict
from backend.sim.timing import SimulatedTiming


class SimulatedDepthCamera(CaptureDevice):
    """Simulated depth frames of one node of the cell.

    A sample holds ``depth`` ((424, 512) float32, m along the optical axis, 0 = no return),
    ``points`` ((N, 3) float64, node frame, m: the valid pixels) and ``intensity`` ((N,) float32 IR
    amplitude of those pixels). ``meta`` holds ``node``, ``frame_index``, ``simulated: True``, the
    ground-truth ``T_world_node`` (4x4 nested list, m), ``intrinsics`` (the pinhole as a dict),
    ``placements`` (the tables standing in the cell, as dicts) and ``pixel_index`` ((N,) flat
    row-major pixel index of each point; an array, so not stored with the capture). Sample ``i``'s
    noise comes from ``(seed, node, i)``, so a sample is the same whatever was read before it.
    """

    driver = "sim_depth"

    def __init__(self, node: str, seed: int = 0, rate_hz: float = 30.0, placements: list[dict] | None = None,
                 disconnect_after: int | None = None):
        """Settings as stored in the rig.

        Args:
            node: the node's name (``sn1`` .. ``sn6``).
            seed: seeds the depth and amplitude noise.
            rate_hz: frame rate to emulate (Hz); 0 renders as fast as possible.
            placements: tables standing in the cell, as :func:`~backend.sim.depth_cell.placement_to_dict` dicts.
            disconnect_after: if set, reads after this many frames raise
                :class:`~backend.devices.base.DeviceDisconnected`, to exercise capture robustness.
        """
        self.node = node
        self.seed = seed
        self.placements = [placement_to_dict(placement_from_dict(p)) for p in placements or []]
        self._timing = SimulatedTiming(rate_hz, disconnect_after, "frames")
        self._layout = default_cell_layout()
        self._T_world_node: np.ndarray | None = None
        self._scene: CellScene | None = None
        self._lock = threading.Lock()

    def open(self) -> None:
        """Place the node and build the cell with its tables."""
        if self._timing.rate_hz < 0:
            raise DeviceError(f"rate_hz must be 0 or more, not {self._timing.rate_hz}", self.describe())
        try:
            self._T_world_node = node_pose(self.node)
            self._scene = CellScene(self._layout, [placement_from_dict(p) for p in self.placements])
        except InputError as exc:
            raise DeviceError(exc.message, self.describe()) from None
        self._timing.restart()

    def set_placements(self, placements: list[TablePlacement] | list[dict[str, Any]]) -> None:
        """Move the tables (:class:`TablePlacement` or their dicts); the next frame read sees them. A bad
        placement raises :class:`InputError` and leaves the tables where they were."""
        parsed = [placement_from_dict(p) for p in placements]
        scene = CellScene(self._layout, parsed)
        with self._lock:
            self.placements = [placement_to_dict(p) for p in parsed]
            if self._scene is not None:
                self._scene = scene

    def read(self) -> Sample:
        """Render the next frame; :class:`~backend.devices.base.DeviceDisconnected` once ``disconnect_after``
        frames were read."""
        if self._T_world_node is None or self._scene is None:
            raise DeviceError("read() before open()", self.describe())
        index = self._timing.next_frame(self.describe())
        with self._lock:
            scene, placements = self._scene, list(self.placements)
        node_number = int("".join(ch for ch in self.node if ch.isdigit()) or 0)
        stamp = time.time()
        frame = scene.render(self._T_world_node, np.random.default_rng([self.seed, node_number, index]),
                             KINECT_V2, stamp)
        points, pixel_index = KINECT_V2.unproject(frame.depth_m)
        meta = {
            "node": self.node,
            "frame_index": index,
            "simulated": True,
            "T_world_node": self._T_world_node.tolist(),
            "intrinsics": KINECT_V2.to_dict(),
            "placements": placements,
            "pixel_index": pixel_index,
        }
        return Sample(stamp, points=points, intensity=frame.amplitude.ravel()[pixel_index], depth=frame.depth_m,
                      meta=meta)

    def close(self) -> None:
        """Forget the scene; safe to call twice."""
        self._T_world_node = None
        self._scene = None

    def describe(self) -> str:
        return f"sim_depth {self.node}"
