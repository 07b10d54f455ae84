"""One dense cloud of a static LiDAR over an integration time the user chooses, kept as a capture with its coverage.

A non-repetitive scanner (the Livox Horizon and Avia) draws a different part of its field of view in every frame:
held still for ``integration_s`` seconds of its own clock it fills the view
(:func:`~backend.devices.accumulate.read_accumulated`), and that one cloud is what the targetless LiDAR-camera
methods and a LiDAR-LiDAR registration against a spinning LiDAR need. The sensor's device is opened for the
capture alone (a Livox LiDAR serves one host: live view must be stopped first), read until the window is full,
and closed; the cloud is stored as an ordinary capture, stamped with the wall-clock time the reading began, whose
``meta`` holds ``integration_s``, ``frames`` and ``coverage`` (the share of the field of view's cells hit).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from backend.calib._session import check_lidar, store_cloud
from backend.core.accumulation import Coverage, check_integration_s
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.devices.accumulate import read_accumulated
from backend.devices.base import DeviceError, Sample, create_device
from backend.store.schema import CaptureRecord
from backend.store.session import Session


@dataclass(frozen=True)
class AccumulatedCapture:
    record: CaptureRecord
    coverage: Coverage

    def to_dict(self) -> dict:
        return {"capture": self.record.model_dump(), "coverage": self.coverage.share,
                "integration_s": self.record.meta["integration_s"], "frames": self.record.meta["frames"]}


def check_device(session: Session, sensor: str) -> dict:
    """``sensor``'s device settings; :class:`InputError` naming it unless it is a LiDAR with a device."""
    check_lidar(session, sensor)
    settings = session.rig.get(sensor).device
    if not settings:
        raise InputError(f"{sensor} has no capture device; set one in the sensors step", sensor)
    return settings


def capture_accumulated(session: Session, sensor: str, integration_s: float,
                        progress: ProgressCallback = no_progress) -> AccumulatedCapture:
    """Read ``sensor``'s device for ``integration_s`` s of its time and keep the accumulated cloud as one capture;
    :class:`InputError` naming the sensor for a sensor without a device, one that cannot be opened, or a bad time."""
    settings = check_device(session, sensor)
    integration_s = check_integration_s(integration_s)
    progress(0.05, f"opening {sensor}'s device")
    try:
        device = create_device(settings)
        device.open()
    except DeviceError as exc:
        raise InputError(exc.message, sensor) from None
    with device:
        session.device_answered(sensor)
        progress(0.2, f"accumulating {integration_s:g} s of {device.describe()}")
        started_s = time.time()
        cloud = read_accumulated(device, integration_s)
        name = device.describe()
    progress(0.95, "storing the cloud")
    meta = {"integration_s": integration_s, "frames": cloud.frames, "coverage": cloud.coverage.share}
    record = store_cloud(session, sensor, Sample(started_s, points=cloud.points, intensity=cloud.intensity, meta=meta),
                         device=name, source=f"{integration_s:g} s accumulated")
    return AccumulatedCapture(record, cloud.coverage)
