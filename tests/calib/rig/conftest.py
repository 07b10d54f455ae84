"""The rig problem's simulated scene: a camera and two LiDARs on ``base_link``, mounted as the demo rig is, and
three noisy results that close a loop between them.

Mounting guesses are the truth off by tape-measure errors (2 cm, 2 deg, stated as such); results are the truth off
by their own stated noise (LiDAR-camera 3 mm / 0.1 deg, LiDAR-LiDAR 2 mm / 0.05 deg). Each test draws its own noise
from its own seed; the truth is computed once.
"""

from __future__ import annotations

import functools

import numpy as np

from backend.core.result import TransformResult
from backend.core.rig import Frame, Rig
from backend.core.transforms import apply_params, invert
from backend.core.verdict import Verdict
from backend.sim.demo_rig import demo_rig

FRAMES = ("cam_front", "lidar_top", "lidar_front")
PRIOR_SIGMA = (0.02, 2.0)
"""Tape-measure mounting guesses: m, deg."""
EDGES = [("cam_front", "lidar_top", 0.003, 0.1, "lidar_camera"),
         ("cam_front", "lidar_front", 0.003, 0.1, "lidar_camera"),
         ("lidar_top", "lidar_front", 0.002, 0.05, "lidar_lidar")]
"""(parent, child, sigma m, sigma deg, kind) of the three results forming the loop."""


@functools.cache
def loop_truth() -> dict[str, np.ndarray]:
    """Each frame's true pose in ``base_link`` (``T_root_frame``), read-only: every test shares them."""
    rig = demo_rig()
    truth = {name: rig.T_root_frame(name) for name in FRAMES}
    for T_root_frame in truth.values():
        T_root_frame.setflags(write=False)
    return truth


def _noise(rng: np.random.Generator, sigma_m: float, sigma_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """A random step and the covariance it was drawn from (TRANSFORM_PARAMETERS)."""
    sigma = np.r_[np.full(3, sigma_m), np.full(3, np.radians(sigma_deg))]
    return rng.normal(0.0, sigma), np.diag(sigma**2)


def measured_results(rng: np.random.Generator) -> list[TransformResult]:
    """The three results of :data:`EDGES`, each the truth off by a step drawn from its stated covariance."""
    truth = loop_truth()
    results = []
    for parent, child, sigma_m, sigma_deg, kind in EDGES:
        step, covariance = _noise(rng, sigma_m, sigma_deg)
        T = apply_params(invert(truth[parent]) @ truth[child], step)
        results.append(TransformResult(kind, "sim", parent, child, T, covariance, verdict=Verdict("trusted", [])))
    return results


def mounted_rig(rng: np.random.Generator) -> Rig:
    """The rig as mounted: each frame on ``base_link`` at the truth off by a tape measure (:data:`PRIOR_SIGMA`)."""
    truth = loop_truth()
    rig = Rig()
    for name in FRAMES:
        step, _ = _noise(rng, *PRIOR_SIGMA)
        rig.add(Frame(name, "base_link", apply_params(truth[name], step), kind="camera" if "cam" in name else "lidar3d",
                      mount_sigma=PRIOR_SIGMA))
    return rig
