"""The simulated LiDAR scene, its ray-caster and the ``simulated_lidar`` driver, against ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from backend.core.boards import BoardSpec
from backend.core.transforms import from_xyz_ypr, transform_points
from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.sim.board_motion import plate_in_view
from backend.sim.demo_rig import DEMO_BOARD, DEMO_LIDAR_CLOCK_OFFSET_S, demo_rig
from backend.sim.lidar_scene import (
    LABELS,
    ROOM_X_M,
    ROOM_Y_M,
    LidarScene,
    default_board_pose,
    moving_board_poses,
    scene_mesh,
)

NOISE_M = 0.01


@pytest.fixture(scope="module")
def rig():
    return demo_rig()


@pytest.fixture(scope="module")
def scene() -> LidarScene:
    return LidarScene()


@pytest.fixture(scope="module")
def scan3d(scene, rig):
    return scene.scan_3d(rig.T_root_frame("lidar_top"), rng=1)


@pytest.fixture(scope="module")
def scan2d(scene, rig):
    return scene.scan_2d(rig.T_root_frame("scanner_2d"), rng=2)


def test_scene_mesh_is_labelled_and_board_sized():
    vertices, triangles, labels = scene_mesh()
    assert vertices.shape[1] == 3 and triangles.shape[1] == 3 and len(labels) == len(triangles)
    assert triangles.max() < len(vertices)
    assert set(np.unique(labels)) == set(LABELS.values())
    # the board plate: the printed size plus one white square on every side, in the board frame
    board = BoardSpec.parse(DEMO_BOARD)
    plate = vertices[np.unique(triangles[labels == LABELS["board"]])]
    plate_board = transform_points(np.linalg.inv(default_board_pose()), plate)
    extent = plate_board.max(axis=0) - plate_board.min(axis=0)
    np.testing.assert_allclose(extent[:2], np.array(board.size_m) + 2 * board.square_m, atol=1e-9)
    assert extent[2] < 0.01
    assert np.isclose(plate_board[:, 2].min(), 0.0, atol=1e-9)  # the print is the face at board z = 0


def test_scan_3d_rings_and_fov(scan3d):
    assert set(np.unique(scan3d.ring)) == set(range(16))
    elevation = np.degrees(np.arcsin(scan3d.points_true[:, 2] / np.linalg.norm(scan3d.points_true, axis=1)))
    assert elevation.min() >= -15 - 1e-6 and elevation.max() <= 15 + 1e-6
    expected = -15 + 2 * scan3d.ring  # evenly spaced beams, ring 0 lowest
    np.testing.assert_allclose(elevation, expected, atol=1e-4)
    assert len(scan3d) > 0.9 * 16 * 1800  # a closed yard: nearly every beam returns
    assert scan3d.points.dtype == np.float64 and scan3d.intensity.dtype == np.float32


def test_scan_3d_lands_on_the_mesh_with_ground_truth(scene, scan3d):
    distance_true = scene.distance_to_mesh(scan3d.points_base(true=True))
    assert distance_true.max() < 3e-3  # Open3D's closest-point query is float32
    distance = scene.distance_to_mesh(scan3d.points_base())
    assert np.median(distance) < NOISE_M
    assert np.percentile(distance, 99) < 3 * NOISE_M
    assert distance.max() < 6 * NOISE_M
    # range noise only: measured points lie on the true rays
    ranges, ranges_true = np.linalg.norm(scan3d.points, axis=1), np.linalg.norm(scan3d.points_true, axis=1)
    assert 0.8 * NOISE_M < np.std(ranges - ranges_true) < 1.2 * NOISE_M
    floor = scan3d.points_base()[scan3d.labels == LABELS["floor"]]
    assert len(floor) > 1000
    assert np.median(np.abs(floor[:, 2])) < NOISE_M and np.abs(floor[:, 2]).max() < 5 * NOISE_M
    # a wrong extrinsic (2 cm up) visibly lifts the floor
    lifted = transform_points(from_xyz_ypr(np.array([0, 0, 0.02]), np.zeros(3)) @ scan3d.T_base_sensor,
                              scan3d.points[scan3d.labels == LABELS["floor"]])
    assert abs(np.median(lifted[:, 2]) - 0.02) < 0.003


def test_board_is_seen_by_both_lidars_and_both_cameras(rig, scan3d, scan2d):
    board = scan3d.labels == LABELS["board"]
    assert board.sum() > 150
    assert len(np.unique(scan3d.ring[board])) >= 3
    assert (scan2d.labels == LABELS["board"]).sum() > 30
    # the board returns the brightest points, its black squares less than its white paper
    board_i = scan3d.intensity[board]
    assert np.median(board_i) > 2 * np.median(scan3d.intensity[~board])
    assert board_i.min() < 100 < board_i.max()
    spec = BoardSpec.parse(DEMO_BOARD)
    for camera in ("cam_front", "cam_wide"):
        T_camera_board = np.linalg.solve(rig.T_root_frame(camera), default_board_pose())
        assert plate_in_view(rig.get(camera).intrinsics, spec, T_camera_board, 10)


def test_scan_2d_is_planar_and_ranges_walls_right(scene, rig, scan2d):
    assert len(scan2d) == 1440  # closed yard, 0.25 deg steps
    assert np.all(scan2d.points[:, 2] == 0.0) and np.all(scan2d.ring == 0)
    assert scene.distance_to_mesh(scan2d.points_base()).max() < 6 * NOISE_M
    T = rig.T_root_frame("scanner_2d")
    origin = T[:3, 3]
    # the beams to the left (+90 deg) and backwards (180 deg) meet the left and back walls
    for angle_deg, axis, wall in ((90.0, 1, ROOM_Y_M[1]), (180.0, 0, ROOM_X_M[0])):
        i = int(np.argmin(np.abs(np.degrees(scan2d.azimuth_rad) - angle_deg)))
        assert scan2d.labels[i] == LABELS["wall"]
        direction = T[:3, :3] @ np.array([np.cos(scan2d.azimuth_rad[i]), np.sin(scan2d.azimuth_rad[i]), 0.0])
        expected_m = (wall - origin[axis]) / direction[axis]
        assert abs(np.linalg.norm(scan2d.points_true[i]) - expected_m) < 1e-4
        assert abs(np.linalg.norm(scan2d.points[i]) - expected_m) < 5 * NOISE_M


def test_scans_are_deterministic_by_seed(scene, rig):
    T = rig.T_root_frame("lidar_top")
    a, b, c = scene.scan_3d(T, rng=5), scene.scan_3d(T, rng=5), scene.scan_3d(T, rng=6)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    assert len(a) != len(c) or not np.array_equal(a.points, c.points)
    T2 = rig.T_root_frame("scanner_2d")
    np.testing.assert_array_equal(scene.scan_2d(T2, rng=3).points, scene.scan_2d(T2, rng=3).points)


def test_lidar_clouds_overlap_in_base_link_with_ground_truth(rig, scan3d, scan2d):
    """What LiDAR-to-LiDAR calibration relies on: 3D points near the scanner's plane lie on its scan line."""
    T_base_scanner = rig.T_root_frame("scanner_2d")

    def median_gap(T_base_scanner_used: np.ndarray) -> tuple[int, float]:
        top = scan3d.points_base()
        height = (top - T_base_scanner[:3, 3]) @ T_base_scanner[:3, 2]
        near = top[np.abs(height) < 0.03]
        gaps, _ = cKDTree(transform_points(T_base_scanner_used, scan2d.points)).query(near)
        return len(near), float(np.median(gaps))

    n_near, gap = median_gap(T_base_scanner)
    assert n_near > 300
    assert gap < 0.035
    _, gap_wrong = median_gap(T_base_scanner @ from_xyz_ypr(np.zeros(3), np.radians([2.0, 0.0, 0.0])))
    assert gap_wrong > 2 * gap


def test_moving_board_poses_stay_in_view():
    rig = demo_rig()
    spec = BoardSpec.parse(DEMO_BOARD)
    poses = moving_board_poses(6, seed=3)
    assert len(poses) == 6 and np.allclose(poses[0], default_board_pose())
    np.testing.assert_array_equal(np.array(poses), np.array(moving_board_poses(6, seed=3)))
    T_lidar = rig.T_root_frame("lidar_top")
    for T_base_board in poses:
        for camera in ("cam_front", "cam_wide"):
            T_camera_board = np.linalg.solve(rig.T_root_frame(camera), T_base_board)
            assert plate_in_view(rig.get(camera).intrinsics, spec, T_camera_board, 10)
        scan = LidarScene(T_base_board).scan_3d(T_lidar, rng=0)
        assert (scan.labels == LABELS["board"]).sum() > 80


def test_driver_reads_scans_with_ground_truth_and_disconnects():
    rig = demo_rig()
    assert rig.get("lidar_top").device == {"driver": "simulated_lidar", "sensor": "lidar_top", "seed": 0,
                                           "clock_offset_s": DEMO_LIDAR_CLOCK_OFFSET_S}
    device = create_device(rig.get("scanner_2d").device | {"disconnect_after": 2})
    with device:
        first = device.read()
        assert first.points.shape == (1440, 3) and np.all(first.points[:, 2] == 0)
        assert first.intensity.shape == (1440,)
        assert first.meta["simulated"] is True and first.meta["sensor"] == "scanner_2d"
        np.testing.assert_allclose(first.meta["T_base_sensor"], rig.T_root_frame("scanner_2d"))
        assert first.meta["frame_index"] == 0
        assert device.read().meta["frame_index"] == 1
        with pytest.raises(DeviceDisconnected):
            device.read()

    device = create_device({"driver": "simulated_lidar", "sensor": "lidar_top", "board_poses": 3, "seed": 4})
    device.open()
    samples = [device.read() for _ in range(4)]
    device.close()
    assert samples[0].points.shape[1] == 3 and len(samples[0].points) > 25000
    assert samples[1].meta["T_base_board"] != samples[0].meta["T_base_board"]
    assert samples[3].meta["T_base_board"] == samples[0].meta["T_base_board"]  # the cycle repeats
    again = create_device({"driver": "simulated_lidar", "sensor": "lidar_top", "board_poses": 3, "seed": 4})
    with again:
        np.testing.assert_array_equal(again.read().points, samples[0].points)

    with pytest.raises(DeviceError, match="no simulated LiDAR"):
        create_device({"driver": "simulated_lidar", "sensor": "cam_front"}).open()
