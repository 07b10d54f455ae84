"""LiDAR-to-LiDAR over several scenes: the joint solve against the simulator's truth, and its verdict.

Scenes are placements of the simulated robot in the yard (VLP-16-like scans, 1 cm range noise, the source's
rear quarter blocked), as in ``test_lidar_lidar.py``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from backend.calib.lidar_lidar.gicp import LidarLidarSettings
from backend.calib.lidar_lidar.scenes import register_pairs
from backend.core.transforms import from_xyz_ypr, transform_error, transform_points
from tests.calib.lidar_lidar.conftest import PLACEMENTS, SCENE_KEYS, T_TRUE, perturbed, scan_pair

KNOCKED = from_xyz_ypr(np.array([0.04, -0.03, 0.0]), np.radians([1.0, 0.0, 0.0]))
"""The source LiDAR knocked by 5 cm and 1 deg before the last scene (its cloud moved by this)."""
NO_SPREAD = LidarLidarSettings(spread=False)


@pytest.fixture(scope="module")
def scenes(scene) -> list[tuple[np.ndarray, np.ndarray]]:
    return [scan_pair(scene, 10 + i, T) for i, T in enumerate(PLACEMENTS)]


@pytest.mark.slow
def test_three_scenes_joint_solve_is_within_3_sigma_and_trusted(scenes) -> None:
    result = register_pairs(scenes, perturbed(T_TRUE, 7, 0.20, 10.0))
    assert result.converged, result.warnings
    err_t, err_r_deg = transform_error(result.T_parent_child, T_TRUE)
    error = np.r_[err_t, np.radians(err_r_deg)]
    assert np.all(np.abs(error) < 3 * result.std_vector), (error, result.std_vector)
    assert np.linalg.norm(err_t) < 0.002 and np.abs(err_r_deg).max() < 0.05
    scenes = result.diagnostics["scenes"]
    # the joint solve is at least as close to the truth as the scenes' own solves, on average
    scene_errors = [np.linalg.norm(transform_error(np.array(s["T_target_source"]), T_TRUE)[0]) for s in scenes]
    assert np.linalg.norm(err_t) <= np.mean(scene_errors)
    assert [s["pairs"] for s in scenes] == [[0], [1], [2]] and all(s["agrees"] for s in scenes)
    assert result.diagnostics["spread_source"] == "scenes"
    assert result.verdict.level == "trusted", result.verdict.reasons
    assert any("cross-check across scenes: all 3 scenes agree" in r for r in result.verdict.reasons)
    record = json.loads(json.dumps(result.to_record(), allow_nan=False))
    assert record["verdict"]["level"] == "trusted" and len(record["diagnostics"]["scenes"]) == 3
    spread = record["diagnostics"]["scene_spread"]
    assert 0 < spread["trans_m"] < 0.01 and 0 < spread["rot_deg"] < 0.2
    assert set(scenes[0]) == SCENE_KEYS


def test_a_knocked_lidar_in_one_scene_fails_the_cross_check(scenes) -> None:
    knocked = [*scenes[:2], (transform_points(KNOCKED, scenes[2][0]), scenes[2][1])]
    result = register_pairs(knocked, perturbed(T_TRUE, 7, 0.20, 10.0), NO_SPREAD)
    assert result.converged  # every scene fits on its own: only the cross-check sees it
    # compared with the joint solve of the others, the knocked scene stands out (the others, each compared
    # with a joint solve that holds it, are pulled by half as much)
    scenes = result.diagnostics["scenes"]
    offsets = [np.linalg.norm(s["deviation"]["trans_m"]) for s in scenes]
    assert not scenes[2]["agrees"] and offsets[2] > 0.04 and offsets[2] > 1.5 * max(offsets[:2]), offsets
    assert result.verdict.level == "reject"
    failed = [r for r in result.verdict.reasons if "cross-check across scenes failed" in r]
    assert failed and "scene 3 (pairs 2)" in failed[0], result.verdict.reasons
    spread = result.diagnostics["scene_spread"]
    assert spread["trans_m"] > 0.04 and spread["rot_deg"] > 0.9


def test_frames_of_a_rig_standing_still_are_one_scene(scene, scenes) -> None:
    """Two frames in one place are not independent scenes: no cross-check, so at best 'check'."""
    result = register_pairs([scenes[0], scan_pair(scene, 20)], perturbed(T_TRUE, 7, 0.05, 2.0), NO_SPREAD)
    assert result.converged
    assert [s["pairs"] for s in result.diagnostics["scenes"]] == [[0, 1]] and result.diagnostics["scene_spread"] is None
    assert result.verdict.level == "check"
    assert any("no cross-check across scenes: only one scene" in r and "2 frame pairs" in r
               for r in result.verdict.reasons), result.verdict.reasons
    err_t, err_r_deg = transform_error(result.T_parent_child, T_TRUE)
    assert np.linalg.norm(err_t) < 0.005 and np.abs(err_r_deg).max() < 0.1


def test_a_bad_cloud_is_named_by_its_pair(scenes) -> None:
    from backend.core.errors import InputError

    with pytest.raises(InputError, match="empty") as exc:
        register_pairs([scenes[0], (scenes[1][0], np.zeros((0, 3)))], T_TRUE, NO_SPREAD,
                       names=[("a.pcd", "b.pcd"), ("c.pcd", "d.pcd")])
    assert exc.value.input == "d.pcd"
