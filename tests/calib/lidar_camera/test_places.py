"""Which pairs were taken in one place: the targetless methods' unit of independent evidence."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib.lidar_camera.places import one_place_note, place_of_pairs
from backend.core.transforms import from_xyz_ypr
from backend.devices.cloud_files import read_cloud
from backend.sim.lidar_scene import LidarScene
from tests.calib.lidar_camera.conftest import ROBOT_POSES, T_BASE_LIDAR
from tests.conftest import SHARED_DATA


@pytest.mark.slow
def test_the_real_vlp16_pairs_of_a_rig_standing_still_are_one_place() -> None:
    """The set's eight clouds: the rig stood in one street while a person carried the board about."""
    folder = SHARED_DATA / "vlp16_camera_checkerboard"
    clouds = [read_cloud(folder / f"lidar{i}.ply").points for i in range(1, 9)]
    assert place_of_pairs(clouds).tolist() == [0] * 8


def test_rescans_in_one_place_group_and_a_moved_robot_does_not() -> None:
    scene = LidarScene(include_board=False)

    def scan(robot_pose: tuple[float, float, float], seed: int) -> np.ndarray:
        x, y, yaw = robot_pose
        T_world_base = from_xyz_ypr(np.array([x, y, 0.0]), np.radians([yaw, 0.0, 0.0]))
        return scene.scan_3d(T_world_base @ T_BASE_LIDAR, rng=seed).points

    clouds = [scan(ROBOT_POSES[0], 1), scan(ROBOT_POSES[1], 2), scan(ROBOT_POSES[0], 3), scan(ROBOT_POSES[2], 4)]
    clouds[2][::7] = np.nan  # non-finite rows are ignored
    assert place_of_pairs(clouds).tolist() == [0, 1, 0, 2]


def test_the_note_says_why_places_cannot_be_cross_checked() -> None:
    assert one_place_note(1, 1, 2).startswith("one pair: pairs from 2 or more places are needed")
    assert one_place_note(8, 1, 3).startswith("the 8 pairs were taken in one place (their clouds lie on each other)")
    assert "taken in 2 places" in one_place_note(4, 2, 3)
