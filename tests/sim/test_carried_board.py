"""The board carried without stopping: continuous in pose, at rest at each place, seen at the same moment by a
simulated LiDAR whose clock runs ahead by its ``clock_offset_s``."""

from __future__ import annotations

import numpy as np
import pytest

from backend.devices.base import DeviceError, create_device
from backend.sim.carried_board import carried_board_pose
from backend.sim.lidar_scene import moving_board_poses

POSES = moving_board_poses(5, seed=3)


def _angle_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def test_the_board_holds_each_place_then_moves_on_smoothly_to_the_next():
    hold_s, carry_s = 1.0, 2.0
    for k in range(len(POSES)):  # held still at place k for hold_s, every cycle
        for t_s in (3.0 * k, 3.0 * k + 0.99, 3.0 * (k + len(POSES))):
            index, T = carried_board_pose(POSES, t_s, hold_s, carry_s)
            assert index == k
            np.testing.assert_allclose(T, POSES[k], atol=1e-12)
    # arriving: the carry ends at the next place, after the last back to the first
    np.testing.assert_allclose(carried_board_pose(POSES, 3.0 * 2 - 1e-9, hold_s, carry_s)[1], POSES[2], atol=1e-6)
    np.testing.assert_allclose(carried_board_pose(POSES, 3.0 * 5 - 1e-9, hold_s, carry_s)[1], POSES[0], atol=1e-6)
    # on the way: halfway in time is halfway in position (the smoothstep is symmetric), and no step jumps
    _, T_half = carried_board_pose(POSES, 1.0 + 1.0, hold_s, carry_s)
    np.testing.assert_allclose(T_half[:3, 3], (POSES[0][:3, 3] + POSES[1][:3, 3]) / 2, atol=1e-12)
    np.testing.assert_allclose(T_half[:3, :3] @ T_half[:3, :3].T, np.eye(3), atol=1e-12)
    times = np.linspace(0.0, 6.0, 1201)  # 5 ms apart
    path = [carried_board_pose(POSES, t, hold_s, carry_s)[1] for t in times]
    steps_m = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in zip(path[:-1], path[1:], strict=True)])
    turns_deg = np.array([_angle_deg(a, b) for a, b in zip(path[:-1], path[1:], strict=True)])
    assert steps_m.max() < 0.01 and turns_deg.max() < 1.0  # under 2 m/s and 200 deg/s: carried, not teleported
    # at rest as it leaves (t = 1 s) and as it arrives (t = 3 s): the smoothstep's zero slope
    assert steps_m[200] < 1e-4 and steps_m[599] < 1e-4 and steps_m[400] > 1e-3

def test_the_lidar_sees_the_carried_board_at_its_true_time_and_stamps_its_own_clock():
    settings = {"driver": "simulated_lidar", "sensor": "lidar_top", "board_poses": 5, "seed": 3,
                "board_carry_s": 2.0, "clock_offset_s": 0.035}
    with create_device(settings) as lidar:
        for _ in range(2):
            sample = lidar.read()
            true_s = sample.timestamp_s - 0.035
            index, T_base_board = carried_board_pose(POSES, true_s, 0.0, 2.0)
            np.testing.assert_allclose(sample.meta["T_base_board"], T_base_board, atol=1e-9)
            assert sample.meta["board_pose_index"] == index
            assert len(sample.points) > 10_000


@pytest.mark.parametrize(("settings", "expected"), [
    ({"driver": "simulated_lidar", "sensor": "lidar_top", "board_carry_s": 2.0},
     "board_carry_s must be 0, or above 0 with board_poses, not 2.0 with 0 board poses"),
    ({"driver": "simulated", "camera": "cam_front", "board_carry_s": 2.0},
     "board_carry_s must be 0, or above 0 with board_motion 'scene', not 2.0 with 'wave'"),
])
def test_a_carry_without_the_yards_board_is_refused(settings, expected):
    with pytest.raises(DeviceError, match=expected):
        create_device(settings).open()
