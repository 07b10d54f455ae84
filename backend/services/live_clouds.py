"""Live point clouds from one LiDAR: the latest scan and a voxel map of the last N scans.

Like :mod:`backend.services.live_capture`, each sensor's device runs in its own
thread so the UI never waits on it. The thread keeps the latest :class:`Sample`
(what "capture" stores) and, when ``accumulate > 1``, merges the last N scans
into one cloud with one point per voxel (the centroid), so the drawn cloud stays
bounded however long it accumulates. Points stay in the sensor's frame (m): the
rig is static while it is calibrated.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from backend.core.voxels import voxel_downsample
from backend.devices.base import Sample
from backend.services.sensor_stream import SensorStream
from backend.store.session import Session

DEFAULT_VOXEL_M = 0.03
"""Edge of an accumulation voxel (m)."""


@dataclass
class CloudCallbacks:
    """What a live cloud thread reports; each runs on that thread."""

    frame: Callable[[str, np.ndarray, np.ndarray | None], None]
    """(sensor, points (N, 3) m in the sensor frame, intensity (N,) or None): the cloud to draw."""
    status: Callable[[str, bool], None]
    """(message, is_error); the message names the sensor."""


class LiveClouds(SensorStream):
    """One LiDAR's live loop: read, keep the latest scan, accumulate, report."""

    kept_phrase = "cloud(s) captured"

    def __init__(self, session: Session, sensor: str, callbacks: CloudCallbacks, *, accumulate: int = 1,
                 voxel_m: float = DEFAULT_VOXEL_M, max_hz: float = 10.0):
        super().__init__(session, sensor, callbacks.status, max_hz)
        self.callbacks = callbacks
        self.voxel_m = voxel_m
        self._frames: collections.deque[Sample] = collections.deque(maxlen=max(1, int(accumulate)))
        self._lock = threading.Lock()
        self._new_scan = threading.Condition(self._lock)

    @property
    def accumulate(self) -> int:
        return self._frames.maxlen or 1

    @accumulate.setter
    def accumulate(self, n: int) -> None:
        with self._lock:
            self._frames = collections.deque(self._frames, maxlen=max(1, int(n)))

    @property
    def latest(self) -> Sample | None:
        """The newest scan (what a capture stores), or None before the first."""
        with self._lock:
            return self._frames[-1] if self._frames else None

    def scan_after(self, seen: Sample | None, timeout_s: float) -> Sample | None:
        """The first scan newer than ``seen`` (a scan read after it), waiting up to ``timeout_s`` (s) for one;
        None if none came (the device is slow, reconnecting or stopped)."""
        with self._new_scan:
            self._new_scan.wait_for(lambda: bool(self._frames) and self._frames[-1] is not seen, timeout_s)
            return self._frames[-1] if self._frames and self._frames[-1] is not seen else None

    def accumulated(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The last ``accumulate`` scans merged into a voxel map (the latest scan as it is when N = 1)."""
        with self._lock:
            frames = list(self._frames)
        if not frames:
            return np.zeros((0, 3)), None
        if len(frames) == 1:
            return frames[0].points, frames[0].intensity
        points = np.concatenate([f.points for f in frames])
        intensity = None
        if all(f.intensity is not None for f in frames):
            intensity = np.concatenate([f.intensity for f in frames])
        return voxel_downsample(points, intensity, self.voxel_m)

    def handle(self, sample: Sample) -> None:
        if sample.points is None or len(sample.points) == 0:
            return
        with self._new_scan:
            self._frames.append(sample)
            self._new_scan.notify_all()
        points, intensity = self.accumulated()
        self.callbacks.frame(self.sensor, points, intensity)
