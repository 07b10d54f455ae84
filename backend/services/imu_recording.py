"""Recording an IMU live, for a camera-IMU or LiDAR-IMU solve, with its excitation as it grows.

The IMU's device (its capture settings in the rig: the VN-100 or its simulator) is read on the stream's thread; its
samples are stored as they come, in captures of :data:`CHUNK_S` seconds each (``meta["imu_run"]`` names the run), so
an unplugged IMU loses at most the last chunk's worth. The run's samples are kept in memory too, up to
:data:`MAX_RUN_S` seconds at the IMU's rate, for the live excitation bars (:func:`~backend.calib.camera_imu.checks.
excitation`: the RMS rate about each axis and the specific force's spread along each) and for the solve once the run
stops.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from backend.calib.camera_imu.checks import Excitation, excitation
from backend.core.imu import ImuSamples
from backend.devices.base import Sample
from backend.services.sensor_stream import SensorStream, StatusCallback
from backend.store.session import Session

CHUNK_S = 2.0
"""Seconds of samples stored per capture."""
MAX_RUN_S = 600.0
"""Longest run (s) kept in memory; longer runs stop being added to (their chunks are still stored)."""
MIN_EXCITATION_SAMPLES = 50
"""Samples before the excitation is worth showing."""


def _joined(parts: list[ImuSamples]) -> ImuSamples:
    return ImuSamples(np.concatenate([p.t_s for p in parts]), np.vstack([p.gyro_rad_s for p in parts]),
                      np.vstack([p.accel_m_s2 for p in parts]))


class ImuRecorder(SensorStream):
    """Streams an IMU into chunked captures and keeps the run for its excitation and the solve."""

    kept_phrase = "IMU capture(s) of 2 s"

    def __init__(self, session: Session, sensor: str, status: StatusCallback):
        super().__init__(session, sensor, status, max_hz=0)
        self.run = f"run-{time.strftime('%Y%m%d-%H%M%S')}"
        """The name the run's captures carry in ``meta["imu_run"]``."""
        self._lock = threading.Lock()
        self._kept: list[ImuSamples] = []
        self._pending: list[ImuSamples] = []
        self._span_s = 0.0

    def handle(self, sample: Sample) -> None:
        if sample.imu is None or not len(sample.imu.t_s):
            return
        with self._lock:
            if self._span_s < MAX_RUN_S:
                self._kept.append(sample.imu)
                self._span_s = float(sample.imu.t_s[-1] - self._kept[0].t_s[0])
            self._pending.append(sample.imu)
            full = self._pending[-1].t_s[-1] - self._pending[0].t_s[0] >= CHUNK_S
        if full:
            self.flush()

    def flush(self) -> None:
        """Store the samples not yet stored as one capture (also after the stream stopped)."""
        with self._lock:
            pending, self._pending = self._pending, []
        if pending:
            chunk = _joined(pending)
            self.session.add_imu_capture(self.sensor, chunk, {"timestamp_s": float(chunk.t_s[0]),
                                                              "device": self.device_name,
                                                              "meta": {"imu_run": self.run}})

    def samples(self) -> ImuSamples | None:
        """The run's samples so far (at most :data:`MAX_RUN_S`), or None before the first."""
        with self._lock:
            return _joined(self._kept) if self._kept else None

    def excitation(self) -> Excitation | None:
        """The run's excitation so far, or None with fewer than :data:`MIN_EXCITATION_SAMPLES` samples."""
        samples = self.samples()
        return None if samples is None or len(samples.t_s) < MIN_EXCITATION_SAMPLES else excitation(samples)
