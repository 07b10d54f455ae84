"""The simulated yard photograph: the fast, shared rendering (the yard cast once per camera, only the board's rays
per pose) gives the same pixels as rendering the whole scene, and is shared by every simulated camera."""

from __future__ import annotations

import numpy as np
import pytest

from backend.devices.base import create_device
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import LidarScene, moving_board_poses
from backend.sim.scene_camera import clean_yard_image, render_scene_image

RIG = demo_rig()


@pytest.mark.parametrize("camera", ["cam_front", "cam_right"])
@pytest.mark.slow
def test_the_yard_rendered_per_board_pose_matches_the_whole_scene(camera: str) -> None:
    intrinsics, T_base_camera = RIG.get(camera).intrinsics, RIG.T_root_frame(camera)
    fast = []
    for pose in moving_board_poses(5)[1::3]:
        whole = render_scene_image(LidarScene(pose), intrinsics, T_base_camera, 0, supersample=1, noise_sigma=0.0)
        fast.append(clean_yard_image(pose, DEMO_BOARD, intrinsics, T_base_camera, 0))
        assert fast[-1].dtype == np.uint8 and fast[-1].shape == whole.shape
        differ = np.abs(fast[-1].astype(int) - whole) > 0
        # the nearest hit of the whole mesh is the nearer of the yard's and the board's: the same pixels, bar a tie
        assert differ.sum() <= 10, (camera, int(differ.sum()))
    assert (fast[0] != fast[1]).sum() > 2000  # the board moved in the picture: the per-pose part was exercised


def test_simulated_cameras_share_one_photograph_per_pose() -> None:
    settings = {"driver": "simulated", "camera": "cam_front", "board_motion": "scene", "n_poses": 4}
    with create_device(settings) as first:
        a = first.read()
    with create_device(settings) as second:  # a device opened anew (as a capture does) renders nothing again
        b = second.read()
    pose = moving_board_poses(4)[0]
    shared = clean_yard_image(pose, DEMO_BOARD, RIG.get("cam_front").intrinsics, RIG.T_root_frame("cam_front"), 0)
    assert not shared.flags.writeable
    assert a.meta["board_pose_index"] == b.meta["board_pose_index"] == 0
    np.testing.assert_array_equal(a.image, b.image)  # frame 0 of the same seed: the same noise too
    noise = a.image.astype(float) - shared
    assert 1.0 < noise.std() < 2.0  # SCENE_NOISE_SIGMA on top of the shared noise-free photograph
