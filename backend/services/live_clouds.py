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
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from backend.devices.base import DeviceDisconnected, DeviceError, Sample, create_device
from backend.store.session import Session

DEFAULT_VOXEL_M = 0.03
"""Edge of an accumulation voxel (m)."""


def voxel_downsample(points: np.ndarray, intensity: np.ndarray | None, voxel_m: float
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """One point per occupied ``voxel_m`` cube (the centroid of its points, and their mean intensity).

    Vectorised voxel hashing: integer voxel indices are packed into one int64 key
    (21 bits per axis, so +-1 million voxels per axis), grouped with ``np.unique``
    and averaged with ``np.bincount``.
    """
    if len(points) == 0:
        return points.reshape(0, 3), intensity
    cells = np.floor(points / voxel_m).astype(np.int64) + (1 << 20)
    keys = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    centroid = np.stack([np.bincount(inverse, weights=points[:, k]) for k in range(3)], axis=1) / counts[:, None]
    mean_intensity = None
    if intensity is not None:
        mean_intensity = (np.bincount(inverse, weights=intensity) / counts).astype(np.float32)
    return centroid, mean_intensity


@dataclass
class CloudCallbacks:
    """What a live cloud thread reports; each runs on that thread."""

    frame: Callable[[str, np.ndarray, np.ndarray | None], None]
    """(sensor, points (N, 3) m in the sensor frame, intensity (N,) or None): the cloud to draw."""
    status: Callable[[str, bool], None]
    """(message, is_error); the message names the sensor."""


class LiveClouds:
    """One LiDAR's live loop: read, keep the latest scan, accumulate, report."""

    def __init__(self, session: Session, sensor: str, callbacks: CloudCallbacks, *, accumulate: int = 1,
                 voxel_m: float = DEFAULT_VOXEL_M, max_hz: float = 10.0):
        self.session = session
        self.sensor = sensor
        self.callbacks = callbacks
        self.voxel_m = voxel_m
        self._min_period_s = 1.0 / max_hz if max_hz > 0 else 0.0
        self._frames: collections.deque[Sample] = collections.deque(maxlen=max(1, int(accumulate)))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.device_name = sensor
        self.frames_seen = 0
        self.rate_hz = 0.0
        """Frames per second reported to ``callbacks.frame`` (smoothed)."""

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

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"live-cloud-{self.sensor}", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        settings = self.session.rig.get(self.sensor).device
        try:
            if not settings:
                raise DeviceError("no capture device configured for this sensor; set one in the sensors step",
                                  self.sensor)
            device = create_device(settings)
            device.open()
        except DeviceError as exc:
            self.callbacks.status(f"{self.sensor}: {exc}", True)
            return
        self.device_name = device.describe()
        self.callbacks.status(f"{self.sensor}: live from {self.device_name}", False)
        last = time.perf_counter()
        period = 1.0
        try:
            while not self._stop.is_set():
                started = time.perf_counter()
                sample = device.read()
                if sample.points is None or len(sample.points) == 0:
                    continue
                with self._lock:
                    self._frames.append(sample)
                self.frames_seen += 1
                points, intensity = self.accumulated()
                self.callbacks.frame(self.sensor, points, intensity)
                now = time.perf_counter()
                period = now - last if self.frames_seen == 1 else 0.8 * period + 0.2 * (now - last)
                self.rate_hz = 1.0 / max(period, 1e-6)
                last = now
                time.sleep(max(0.0, self._min_period_s - (time.perf_counter() - started)))
        except DeviceDisconnected as exc:
            kept = len(self.session.captures(self.sensor))
            self.callbacks.status(f"{self.sensor}: {exc} - the {kept} cloud(s) captured so far are kept", True)
        except Exception as exc:  # noqa: BLE001 - a live thread must end with a message, never silently
            self.callbacks.status(f"{self.sensor}: live stopped: {exc!r}", True)
        finally:
            device.close()
