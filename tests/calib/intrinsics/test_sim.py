"""Intrinsics against the simulator's ground truth, and whether the reported sigmas are honest."""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.solver import IntrinsicsResult, IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.devices.base import create_device
from backend.sim.demo_rig import DEMO_BOARD, demo_rig

BOARD = BoardSpec.parse(DEMO_BOARD)
HONESTY_SEEDS = 3
"""Seeds of the honesty test: 24 normalised errors. With 15 views all 48 of 6 seeds (and all 64 of 8) lie within
3 sigma, rms 1.08 (1.09); with 12 views the jackknife is too short for its sigmas (95 % within, rms 1.06). The
thorough measure, per parameter over 30 seeds, is ``benchmarks/sigma_calibration.py``; three seeds here keep
the suite inside CI's time."""
VIEWS = 15


@functools.cache
def simulated_views(camera: str, seed: int, count: int) -> list[View]:
    """The board views ``count`` frames of the simulated ``camera`` give (rendered and detected once per process:
    the honesty test and the analytic-sigma test share seed 0). Views are not changed by the solver."""
    with create_device({"driver": "simulated", "camera": camera, "seed": seed}) as device:
        images = [device.read().image for _ in range(count)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        detections = list(pool.map(lambda image: detect_board(image, BOARD), images))
    return [View(f"{camera}_{seed}_{i}", d) for i, d in enumerate(detections) if d is not None]


def normalised_errors(result: IntrinsicsResult, truth: CameraIntrinsics, n_dist: int) -> np.ndarray:
    """(estimate - truth) / sigma for fx, fy, cx, cy and the first ``n_dist`` coefficients."""
    K, Kt = result.camera.K, truth.K
    estimate = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], result.camera.dist[:n_dist]]
    true = np.r_[Kt[0, 0], Kt[1, 1], Kt[0, 2], Kt[1, 2], truth.dist[:n_dist]]
    sigma = np.r_[result.std["fx"], result.std["fy"], result.std["cx"], result.std["cy"], result.std["dist"][:n_dist]]
    assert np.all(sigma > 0)
    return (estimate - true) / sigma


@pytest.mark.slow
@pytest.mark.parametrize(("camera", "settings", "n_dist"), [
    ("cam_front", IntrinsicsSettings(), 4),
    ("cam_wide", IntrinsicsSettings(estimate_k3=True), 5),
])
def test_recovers_ground_truth_within_3_sigma(camera, settings, n_dist):
    truth = demo_rig().get(camera).intrinsics
    views = simulated_views(camera, seed=11, count=20)
    assert len(views) >= 18
    result = calibrate_intrinsics(views, BOARD, truth.image_size, settings)
    z = normalised_errors(result, truth, n_dist)
    # 3.5, not 3: one of 8 errors beyond 3 sigma happens in ~2 % of seeds; test_sigmas_are_honest_over_seeds
    # checks the distribution (with the refined corners, k2 of this seed lands at 3.05 sigma)
    assert np.all(np.abs(z) < 3.5), f"normalised errors {np.round(z, 2)}"
    assert result.rms_px < 0.2
    assert abs(result.camera.K[0, 0] - truth.K[0, 0]) < 0.003 * truth.K[0, 0]


@pytest.mark.slow
def test_sigmas_are_honest_over_seeds():
    """Over repeated seeds about 99 % of errors fall within 3 sigma, and sigmas are not inflated either."""
    truth = demo_rig().get("cam_front").intrinsics
    z = np.concatenate([
        normalised_errors(calibrate_intrinsics(simulated_views("cam_front", seed, VIEWS), BOARD, truth.image_size),
                          truth, 4)
        for seed in range(HONESTY_SEEDS)
    ])
    within = np.mean(np.abs(z) < 3)
    rms = float(np.sqrt(np.mean(z**2)))
    assert within >= 0.95, f"only {within:.0%} of {z.size} errors within 3 sigma (rms z {rms:.2f})"
    assert 0.6 < rms < 1.5, f"normalised error rms {rms:.2f}: sigmas are {'too small' if rms > 1 else 'inflated'}"


@pytest.mark.slow
def test_analytic_sigmas_alone_would_be_too_small():
    """Why the jackknife is there: without it, sigmas ignore per-view correlated corner errors."""
    truth = demo_rig().get("cam_front").intrinsics
    views = simulated_views("cam_front", 0, VIEWS)  # positional, as the honesty test asks: one cache entry
    with_jackknife = calibrate_intrinsics(views, BOARD, truth.image_size)
    analytic_only = calibrate_intrinsics(views, BOARD, truth.image_size, IntrinsicsSettings(jackknife=False))
    np.testing.assert_allclose(with_jackknife.camera.K, analytic_only.camera.K)
    reported = np.r_[[with_jackknife.std[k] for k in ("fx", "fy", "cx", "cy")], with_jackknife.std["dist"]]
    analytic = np.r_[[analytic_only.std[k] for k in ("fx", "fy", "cx", "cy")], analytic_only.std["dist"]]
    assert np.all(reported >= analytic * (1 - 1e-9))
    # per-view errors widen some parameters' sigmas (which ones depends on the views: on the demo's first 15, cy
    # and p1 by about 1.4x) and with them the projection sigma
    widened = reported[analytic > 0] / analytic[analytic > 0]
    assert widened.max() > 1.25, widened
    assert (with_jackknife.projection_uncertainty["max_px"]
            > 1.02 * analytic_only.projection_uncertainty["max_px"])


def test_degenerate_views_are_rejected():
    from backend.core.errors import InputError

    views = simulated_views("cam_front", seed=0, count=1) * 5
    with pytest.raises(InputError, match="nearly the same place"):
        calibrate_intrinsics(views, BOARD, (1280, 720))
    with pytest.raises(InputError, match="at least 3"):
        calibrate_intrinsics(views[:2], BOARD, (1280, 720))
