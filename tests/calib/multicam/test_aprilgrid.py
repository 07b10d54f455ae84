"""Kalibr's AprilGrid on the multi-camera path: a rendered stereo pair (12 cm apart, the left lens given, the board
often cut by the image's edge) solved by ``calib-studio multicam --board aprilgrid:...``, the baseline checked
against the truth."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.core.boards import BoardSpec
from backend.core.transforms import invert, make_T, transform_error
from backend.exports.ros_camera_info import write_camera_info
from backend.sim.board_motion import board_poses
from backend.sim.board_renderer import render_board_image
from backend.sim.camera_imu import CAMERA
from tests.conftest import cli_in_process

pytestmark = pytest.mark.slow

SPEC = "aprilgrid:6x6:0.088:0.3"
T_LEFT_RIGHT = make_T(Rotation.from_euler("xyz", [0.5, -2.0, 1.0], degrees=True).as_matrix(), [0.12, 0.003, -0.004])


def test_a_stereo_pair_calibrates_on_an_aprilgrid(tmp_path) -> None:
    board = BoardSpec.parse(SPEC)
    folders = {side: tmp_path / side for side in ("left", "right")}
    for folder in folders.values():
        folder.mkdir()
    poses = board_poses(CAMERA, board, 14, seed=2, fill=(0.45, 0.8))
    for k, T_left_board in enumerate(poses):
        for side, T in (("left", T_left_board), ("right", invert(T_LEFT_RIGHT) @ T_left_board)):
            image = render_board_image(CAMERA, board, T, np.random.default_rng([k, side == "right"]))
            cv2.imwrite(str(folders[side] / f"{side}{k:02d}.png"), image)
    write_camera_info(tmp_path / "left.yaml", CAMERA, "left")
    run = cli_in_process("multicam", "--camera", f"left={folders['left']}", "--camera", f"right={folders['right']}",
                         "--board", SPEC, "--intrinsics", f"left={tmp_path / 'left.yaml'}", "--json")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    trans_m, rot_deg = transform_error(np.array(summary["T_ref_cam"]["right"]), T_LEFT_RIGHT)
    print(f"AprilGrid stereo: baseline {1e3 * np.linalg.norm(trans_m):.2f} mm, {np.linalg.norm(rot_deg):.3f} deg "
          f"off; RMS {summary['rms_px']}")
    assert np.linalg.norm(trans_m) < 2e-3 and np.linalg.norm(rot_deg) < 0.1, (trans_m, rot_deg)
    assert all(v < 0.5 for v in summary["rms_px"].values()), summary["rms_px"]
