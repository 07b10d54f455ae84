"""The simulated rig: rendered boards match ground truth closely enough to calibrate from."""

from __future__ import annotations

from itertools import islice

import cv2
import numpy as np
import pytest

from backend.calib.board.coverage import FULL_CELLS, HEATMAP_CELLS
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.sim.board_motion import board_poses, covering_poses, plate_in_view, project_corners
from backend.sim.board_renderer import render_board_image
from backend.sim.camera_device import SimulatedCamera
from backend.sim.demo_rig import DEMO_BOARD, demo_rig

BOARD = BoardSpec.parse(DEMO_BOARD)


def _intrinsics(name: str) -> CameraIntrinsics:
    intrinsics = demo_rig().get(name).intrinsics
    assert intrinsics is not None
    return intrinsics


def _views(name: str, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` rendered views of a demo camera: (true corners (N, 2), image)."""
    camera = _intrinsics(name)
    views = []
    for i, T_camera_board in enumerate(board_poses(camera, BOARD, n, seed)):
        image = render_board_image(camera, BOARD, T_camera_board, np.random.default_rng([seed, i]))
        views.append((project_corners(camera, BOARD, T_camera_board), image))
    return views


def _detect(image: np.ndarray, truth: np.ndarray, flags: int = cv2.CALIB_CB_ACCURACY) -> np.ndarray | None:
    """Detected corners (N, 2) in ground-truth order (OpenCV may start from the other end), or None."""
    found, corners = cv2.findChessboardCornersSB(image, BOARD.corner_grid, flags=flags)
    if not found:
        return None
    corners = corners.reshape(-1, 2).astype(float)
    return min(corners, corners[::-1], key=lambda c: np.linalg.norm(c - truth, axis=1).mean())


def test_demo_rig_ground_truth() -> None:
    rig = demo_rig()
    assert {f.name: f.kind for f in rig.sensors()} == {
        "cam_front": "camera",
        "cam_wide": "camera",
        "cam_right": "camera",
        "lidar_top": "lidar3d",
        "lidar_front": "lidar3d",
        "scanner_2d": "lidar2d",
        "sweep_3d": "lidar3d",
    }
    T_front_wide = rig.T_a_b("cam_front", "cam_wide")
    assert 0.1 <= np.linalg.norm(T_front_wide[:3, 3]) <= 0.2
    T_front_right = rig.T_a_b("cam_front", "cam_right")  # a stereo pair: 12 cm along the front camera's x
    assert T_front_right[0, 3] == pytest.approx(0.12, abs=0.005) and np.abs(T_front_right[1:3, 3]).max() < 0.01
    # Optical z of each camera looks roughly along body +x.
    for name in ("cam_front", "cam_wide", "cam_right"):
        assert rig.T_root_frame(name)[:3, 2] @ [1.0, 0.0, 0.0] > 0.98
        assert rig.get(name).device == {"driver": "simulated", "camera": name, "seed": 0}


@pytest.mark.parametrize("name", ["cam_front", "cam_wide"])
@pytest.mark.slow
def test_rendered_corners_match_ground_truth(name: str) -> None:
    detections = [(truth, _detect(image, truth)) for truth, image in _views(name, 6, seed=5)]
    assert all(detected is not None for _, detected in detections), "board not found in every view"
    errors = np.concatenate([np.linalg.norm(detected - truth, axis=1) for truth, detected in detections])
    print(f"{name}: corner error median {np.median(errors):.3f} px, p95 {np.percentile(errors, 95):.3f} px")
    assert np.median(errors) < 0.15


def test_rendering_is_deterministic() -> None:
    camera = _intrinsics("cam_wide")
    T_camera_board = board_poses(camera, BOARD, 1, seed=0)[0]
    first = render_board_image(camera, BOARD, T_camera_board, np.random.default_rng(7))
    again = render_board_image(camera, BOARD, T_camera_board, np.random.default_rng(7))
    other = render_board_image(camera, BOARD, T_camera_board, np.random.default_rng(8))
    assert first.dtype == np.uint8 and first.shape == (camera.height, camera.width)
    assert np.array_equal(first, again)
    assert not np.array_equal(first, other)


def test_board_poses_are_varied_and_in_view() -> None:
    camera = _intrinsics("cam_wide")
    poses = board_poses(camera, BOARD, 18, seed=1)
    assert all(np.array_equal(a, b) for a, b in zip(poses[:5], board_poses(camera, BOARD, 5, seed=1), strict=True))
    assert all(plate_in_view(camera, BOARD, T, margin_px=4.0) for T in poses)
    corners = np.concatenate([project_corners(camera, BOARD, T) for T in poses])
    # Corners land all over the image: in every cell of a 3x3 grid and nearly every cell of a 5x5 one.
    for grid, least in ((3, 9), (5, 20)):
        cells = {(int(grid * u / camera.width), int(grid * v / camera.height)) for u, v in corners}
        assert len(cells) >= least, f"corners in only {len(cells)} of {grid}x{grid} image cells"
    tilts_deg = [np.degrees(np.arccos(T[2, 2])) for T in poses]
    assert max(tilts_deg) > 25


@pytest.mark.parametrize("name", ["cam_front", "cam_wide"])
def test_covering_poses_reach_the_coverage_cells(name: str) -> None:
    """The demo camera's board motion: 150 poses put corners into at least the share of the coverage heat map
    that "enough data" asks (corners included, on the wide lens too), with the whole plate in view and no
    square smaller than 9 px."""
    camera = _intrinsics(name)
    poses = list(islice(covering_poses(camera, BOARD, seed=0), 150))
    again = islice(covering_poses(camera, BOARD, seed=0), 5)
    assert all(np.array_equal(a, b) for a, b in zip(poses[:5], again, strict=True))
    assert all(plate_in_view(camera, BOARD, T, margin_px=4.0) for T in poses)
    heatmap = np.zeros(HEATMAP_CELLS[::-1], bool)
    smallest_square_px = np.inf
    for T in poses:
        corners = project_corners(camera, BOARD, T)
        cells = np.floor(corners / camera.image_size * HEATMAP_CELLS).astype(int)
        heatmap[cells[:, 1], cells[:, 0]] = True
        grid = corners.reshape(BOARD.corner_grid[1], BOARD.corner_grid[0], 2)
        smallest_square_px = min(smallest_square_px, np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    assert heatmap.mean() >= FULL_CELLS, f"corners in {heatmap.mean():.0%} of the heat map's cells"
    assert heatmap[[0, 0, -1, -1], [0, -1, 0, -1]].sum() >= 3, "the image corners are not reached"
    assert smallest_square_px > 9


@pytest.mark.slow
def test_calibration_recovers_intrinsics() -> None:
    camera = _intrinsics("cam_front")
    # The plain (faster) detector is accurate enough to calibrate from.
    detections = [_detect(image, truth, flags=0) for truth, image in _views("cam_front", 25, seed=3)]
    image_points = [corners.astype(np.float32) for corners in detections if corners is not None]
    assert len(image_points) >= 23
    object_points = [BOARD.object_points] * len(image_points)
    rms, K, _, _, _ = cv2.calibrateCamera(object_points, image_points, camera.image_size, None, None)
    print(f"calibration rms {rms:.3f} px, fx fy cx cy {K[0, 0]:.2f} {K[1, 1]:.2f} {K[0, 2]:.2f} {K[1, 2]:.2f}")
    assert rms < 0.2
    assert K[0, 0] == pytest.approx(camera.K[0, 0], rel=0.005)
    assert K[1, 1] == pytest.approx(camera.K[1, 1], rel=0.005)
    assert K[0, 2] == pytest.approx(camera.K[0, 2], abs=2.0)
    assert K[1, 2] == pytest.approx(camera.K[1, 2], abs=2.0)


def test_simulated_camera_disconnects_after_n_reads() -> None:
    device = create_device({"driver": "simulated", "camera": "cam_front", "n_poses": 4, "disconnect_after": 3})
    assert isinstance(device, SimulatedCamera)
    samples = []
    with device:
        for _ in range(3):
            samples.append(device.read())
        with pytest.raises(DeviceDisconnected):
            device.read()
        with pytest.raises(DeviceDisconnected):
            device.read()
    assert [s.meta["frame_index"] for s in samples] == [0, 1, 2]
    for sample in samples:
        assert sample.image is not None and sample.image.shape == (720, 1280) and sample.image.dtype == np.uint8
        assert sample.meta["simulated"] is True
        assert np.asarray(sample.meta["T_camera_board"]).shape == (4, 4)
    assert not np.array_equal(samples[0].image, samples[1].image)


def test_simulated_camera_rejects_unknown_camera() -> None:
    with pytest.raises(DeviceError, match="cam_nope"):
        SimulatedCamera(camera="cam_nope").open()
    with pytest.raises(DeviceError, match="scanner_2d"):
        SimulatedCamera(camera="scanner_2d").open()
