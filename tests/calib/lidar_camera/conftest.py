"""The LiDAR-to-camera scene the problem's tests share: ``cam_front`` and ``lidar_front`` of the demo rig in the
simulated yard, the truth between them (:data:`TRUTH`), starts off it (:func:`initial_guess`) and targetless image
and cloud pairs (:func:`edge_pairs_folder`, rendered once per run).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.lidar_camera.edges import EdgeObservation
from backend.core.transforms import from_xyz_ypr, make_T, transform_error
from backend.sim.demo_rig import CAM_FRONT, demo_rig
from backend.sim.lidar_scene import LidarScene
from backend.sim.scene_camera import render_scene_image
from tests.conftest import built_once

RIG = demo_rig()
T_BASE_CAMERA = RIG.T_root_frame("cam_front")
T_BASE_LIDAR = RIG.T_root_frame("lidar_front")
TRUTH = RIG.T_a_b("cam_front", "lidar_front")
ROBOT_POSES = ((0.0, 0.0, 0.0), (0.6, -0.9, -20.0), (-0.6, 1.0, 25.0), (1.5, 0.3, 10.0))
"""Where the robot stands in the yard for each pair: x, y (m) and heading (deg)."""


def scan_and_image(scene: LidarScene, robot_pose: tuple[float, float, float], rng: np.random.Generator):
    """A dense 128-beam scan (40 deg, 0.1 deg steps) by ``lidar_front`` and ``cam_front``'s image, robot at a pose."""
    x, y, yaw = robot_pose
    T_world_base = from_xyz_ypr(np.array([x, y, 0.0]), np.radians([yaw, 0.0, 0.0]))
    scan = scene.scan_3d(T_world_base @ T_BASE_LIDAR, beams=128, vertical_fov_deg=(-25, 15), azimuth_step_deg=0.1,
                         rng=rng)
    return scan, render_scene_image(scene, CAM_FRONT, T_world_base @ T_BASE_CAMERA, rng)


def edge_pairs_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The targetless scene as files, rendered once per run (:func:`~tests.conftest.built_once`): for each of
    :data:`ROBOT_POSES`, ``sceneN.png`` (cam_front's image) and ``sceneN.npy`` (lidar_front's dense scan: x, y,
    z in m and the intensity) of the yard without the board.

    The board is left out because a checkerboard is a periodic pattern (its own tests are under "a repeating
    pattern in view"). The solver's tests read them (:func:`edge_pairs`), the CLI's pass the files.
    """
    return built_once(tmp_path_factory, "lidar_camera_edge_pairs", _write_edge_pairs)


def _write_edge_pairs(folder: Path) -> None:
    scene, rng = LidarScene(include_board=False), np.random.default_rng(0)
    for pose, (image_file, cloud_file) in zip(ROBOT_POSES, edge_pair_files(folder), strict=True):
        scan, image = scan_and_image(scene, pose, rng)
        cv2.imwrite(str(image_file), image)
        np.save(cloud_file, np.column_stack([scan.points, scan.intensity]))


def edge_pair_files(folder: Path) -> list[tuple[Path, Path]]:
    """The (image, cloud) files of :func:`edge_pairs_folder`, one per robot pose, in pose order."""
    return [(folder / f"scene{i}.png", folder / f"scene{i}.npy") for i in range(len(ROBOT_POSES))]


def edge_pairs(folder: Path) -> list[EdgeObservation]:
    """The pairs of :func:`edge_pairs_folder`, read back (the PNGs are lossless)."""
    return [EdgeObservation(cv2.imread(str(image), cv2.IMREAD_UNCHANGED), np.load(cloud), f"pose {i + 1}")
            for i, (image, cloud) in enumerate(edge_pair_files(folder))]


def initial_guess(seed: int) -> np.ndarray:
    """The truth off by 10 cm and 5 deg in random directions."""
    rng = np.random.default_rng(seed)
    axis, direction = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
    return TRUTH @ make_T(Rotation.from_rotvec(np.radians(5.0) * axis).as_matrix(), 0.1 * direction)


def errors_and_sigmas(result, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(6,) error (m, m, m, deg, deg, deg) against ``T_true`` and the reported 1-sigma in the same units."""
    err_t, err_r = transform_error(result.T_parent_child, T_true)
    return np.r_[err_t, err_r], np.r_[result.std["trans_m"], result.std["rot_deg"]]
