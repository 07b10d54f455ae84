"""The swept scanner's simulated scene, built once per test process: one full sweep of the simulated yard through
the byte-level Dynamixel simulator, assembled with the true geometry."""

from __future__ import annotations

import time

import pytest

from backend.devices.base import Sample, create_device
from backend.sim.demo_rig import DEFAULT_SIM_GEOMETRY


@pytest.fixture(scope="session")
def full_sweep() -> tuple[Sample, float]:
    """One 173-step half-sphere sweep of the simulated yard, assembled with the TRUE geometry, and its seconds."""
    dev = create_device({"driver": "swept_scanner", "servo_port": "sim", "steps": 173, "geometry": DEFAULT_SIM_GEOMETRY,
                         "scanner": {"driver": "sim", "seed": 1}})
    dev.open()
    try:
        started = time.monotonic()
        sample = dev.read()
        seconds = time.monotonic() - started
    finally:
        dev.close()
    return sample, seconds
