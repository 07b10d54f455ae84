"""Frame numbering, rate pacing and a scripted unplug, shared by the simulated drivers."""

from __future__ import annotations

import time

from backend.devices.base import DeviceDisconnected


def held_pose_index(frame_index: int, n_poses: int, hold_s: float) -> int:
    """Which of ``n_poses`` board poses a simulated device sees: pose ``frame_index % n_poses``, or with
    ``hold_s > 0`` the pose a person holds still for ``hold_s`` seconds at a time on the wall clock.

    The wall clock is shared by every simulated device, so a camera and a LiDAR read within the same
    hold see the same pose (as real sensors do when the board is held still between captures).
    """
    if hold_s > 0:
        return int(time.time() // hold_s) % n_poses
    return frame_index % n_poses


class SimulatedTiming:
    """Hands out frame indices at up to ``rate_hz`` (0: as fast as asked) and unplugs after ``disconnect_after``."""

    def __init__(self, rate_hz: float, disconnect_after: int | None, noun: str):
        self.rate_hz = rate_hz
        self.disconnect_after = disconnect_after
        self.noun = noun
        """What a frame is, plural, for the disconnect message: ``"frames"``, ``"scans"``."""
        self.frames_read = 0
        self._next_frame_s = 0.0

    def restart(self) -> None:
        """Start counting and pacing from now (on ``open()``)."""
        self.frames_read = 0
        self._next_frame_s = time.monotonic()

    def next_frame(self, device: str) -> int:
        """Wait for the next frame's time and return its index; :class:`DeviceDisconnected` when unplugged."""
        if self.disconnect_after is not None and self.frames_read >= self.disconnect_after:
            raise DeviceDisconnected(f"simulated disconnect after {self.disconnect_after} {self.noun}", device)
        if self.rate_hz > 0:
            time.sleep(max(0.0, self._next_frame_s - time.monotonic()))
            self._next_frame_s = max(self._next_frame_s, time.monotonic()) + 1.0 / self.rate_hz
        self.frames_read += 1
        return self.frames_read - 1
