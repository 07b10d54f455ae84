"""Reading a static LiDAR for an integration time of its own clock and accumulating one dense cloud.

:func:`read_accumulated` reads frames from an open :class:`~backend.devices.base.CaptureDevice` into a
:class:`~backend.core.accumulation.CloudAccumulator` until ``integration_s`` (s) of the sensor's time is covered,
and returns the cloud with its coverage of the sensor's field of view (:mod:`backend.core.accumulation`).

A return's time is ``meta["sensor_time_s"] + meta["point_time_s"]`` where the driver gives per-return times (the
Livox drivers), else the frame's ``timestamp_s`` for all its returns (a frame is then taken whole or not at all).
The field of view is the caller's, or the driver's ``meta["fov_deg"]`` (full horizontal and vertical angles, deg)
and ``meta["fov_elliptical"]``.
"""

from __future__ import annotations

import math

import numpy as np

from backend.core.accumulation import (
    DEFAULT_CELL_RAD,
    AccumulatedCloud,
    CloudAccumulator,
    FieldOfView,
    check_integration_s,
)
from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, Sample


def sample_fov(sample: Sample) -> FieldOfView | None:
    """The field of view a driver states in ``meta`` (``fov_deg``, ``fov_elliptical``), or None."""
    fov = sample.meta.get("fov_deg")
    if fov is None:
        return None
    return FieldOfView(math.radians(fov[0]), math.radians(fov[1]), bool(sample.meta.get("fov_elliptical", False)))


def return_times_s(sample: Sample) -> np.ndarray:
    """(N,) the time (s, the sensor's clock) of each return of ``sample``."""
    n = 0 if sample.points is None else len(sample.points)
    offsets = sample.meta.get("point_time_s")
    if offsets is not None and "sensor_time_s" in sample.meta and len(offsets) == n:
        return float(sample.meta["sensor_time_s"]) + np.asarray(offsets, float)
    return np.full(n, float(sample.timestamp_s))


def read_accumulated(device: CaptureDevice, integration_s: float, fov: FieldOfView | None = None,
                     cell_rad: float = DEFAULT_CELL_RAD) -> AccumulatedCloud:
    """``integration_s`` (s) of an open, static ``device``'s returns as one cloud with its coverage.

    Reads until a return at or past the end of the window arrives, so it takes about ``integration_s`` plus a frame
    of wall time from a live sensor. Raises what the device's ``read`` raises (``DeviceDisconnected`` when it stops),
    and :class:`InputError` for a bad ``integration_s`` or ``cell_rad``, or when neither the caller nor the driver
    gives a field of view.
    """
    check_integration_s(integration_s)
    accumulator: CloudAccumulator | None = None
    while accumulator is None or not accumulator.complete:
        sample = device.read()
        if sample.points is None:
            continue
        if accumulator is None:
            fov = fov or sample_fov(sample)
            if fov is None:
                raise InputError(f"{device.describe()} states no field of view; give one to accumulate its "
                                 "coverage", "fov")
            accumulator = CloudAccumulator(integration_s, fov, cell_rad)
        accumulator.add(sample.points, return_times_s(sample), sample.intensity)
    return accumulator.cloud()
