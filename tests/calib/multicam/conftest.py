"""The multi-camera problem's simulated scene, built and solved once per test process: a ring of six cameras."""

from __future__ import annotations

import pytest

from backend.calib.multicam.bundle import MulticamResult, calibrate_multicam
from backend.calib.multicam.graph import Observation
from backend.sim.multicam_rig import SimulatedMulticam, simulated_ring

RING_NOISE_PX = 0.3
"""Corner noise of the ring's observations (px)."""


@pytest.fixture(scope="session")
def ring() -> SimulatedMulticam:
    """Six cameras 40 deg apart: neighbours share frames, cam0 and cam5 never do."""
    return simulated_ring(6, 245, seed=0)


@pytest.fixture(scope="session")
def ring_observations(ring) -> list[Observation]:
    return ring.observations(RING_NOISE_PX, seed=1)


@pytest.fixture(scope="session")
def ring_result(ring, ring_observations) -> MulticamResult:
    return calibrate_multicam(ring.cameras, ring.board, ring_observations)
