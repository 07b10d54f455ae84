"""Frame numbering, rate pacing and a scripted unplug, shared by the simulated drivers."""

from __future__ import annotations

import time

from backend.devices.base import DeviceDisconnected


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
