"""The lens solve from an AprilGrid waved in front of the simulated front camera: partial views of the grid count,
and the lens comes back within its sigma, as from a checkerboard."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.core.boards import BoardSpec
from backend.devices.base import create_device
from backend.sim.demo_rig import demo_rig
from tests.calib.intrinsics.test_sim import normalised_errors

pytestmark = pytest.mark.slow

BOARD = "aprilgrid:6x5:0.045:0.3"


def test_the_front_lens_from_an_aprilgrid() -> None:
    board = BoardSpec.parse(BOARD)
    truth = demo_rig().get("cam_front").intrinsics
    with create_device({"driver": "simulated", "camera": "cam_front", "seed": 4, "board": BOARD}) as device:
        detections = [detect_board(device.read().image, board) for _ in range(20)]
    views = [View(f"v{i}", d) for i, d in enumerate(detections) if d is not None]
    assert len(views) >= 18
    assert any(len(v.detection.ids) < board.n_corners for v in views)  # some views show part of the grid
    result = calibrate_intrinsics(views, board, truth.image_size, IntrinsicsSettings())
    z = normalised_errors(result, truth, 4)
    assert np.all(np.abs(z) < 3.5), f"normalised errors {np.round(z, 2)}"
    assert abs(result.camera.K[0, 0] - truth.K[0, 0]) < 0.003 * truth.K[0, 0]
    print(f"AprilGrid: {len(views)} views, RMS {result.rms_px:.3f} px, fx {result.camera.K[0, 0]:.2f} "
          f"(truth {truth.K[0, 0]:.2f})")
