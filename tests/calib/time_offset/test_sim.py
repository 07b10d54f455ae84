"""The time offset between a camera and a LiDAR from a board carried through both views (simulated: a 37 ms offset,
a spinning LiDAR firing each shot at its own instant), and the refusals of motions that cannot show it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from backend.calib.time_offset.board_signals import camera_board_poses, camera_signal, lidar_signal
from backend.calib.time_offset.signals import MotionSignal, board_normal_signal
from backend.calib.time_offset.solver import TimeOffsetSettings, solve_time_offset
from backend.core.errors import InputError
from backend.sim.moving_board import simulate_moving_board
from tests.conftest import cli_in_process
from tests.time_offset_session import command_files


@pytest.fixture(scope="module")
def recording():
    return simulate_moving_board(duration_s=20.0, offset_s=0.037, seed=1)


@pytest.fixture(scope="module")
def signals(recording):
    times, poses = camera_board_poses(recording.camera, recording.board, recording.camera_t_s, recording.detections)
    camera = camera_signal("cam", recording.camera, recording.board, recording.camera_t_s, recording.detections)
    lidar = lidar_signal("lidar", recording.board, recording.scan_t_s, recording.scans, times, poses,
                         recording.T_camera_lidar)
    return camera, lidar


def test_lidar_camera_offset_within_2_ms_and_3_sigma(recording, signals) -> None:
    camera, lidar = signals
    assert len(camera.t_s) == len(recording.detections) and len(lidar.t_s) > 0.95 * len(recording.scans)
    result = solve_time_offset(camera, lidar)
    error_s = result.offset_s - recording.offset_s
    print(f"LiDAR-camera offset {1e3 * result.offset_s:.2f} ms (truth 37), sigma {1e3 * result.std_s:.2f} ms, "
          f"halves {result.halves.to_dict() if result.halves else None}")
    assert abs(error_s) < 2e-3 and abs(error_s) < 3 * result.std_s, (error_s, result.std_s)
    assert result.std_s <= 2e-3 and result.verdict.level == "trusted", result.verdict.reasons
    assert result.halves is not None and abs(result.halves.difference_s) < 3 * result.halves.expected_s
    summary = result.summary()
    assert summary["time_offset_s"] == result.offset_s and summary["std"]["time_s"] == result.std_s
    assert set(result.to_record()["signals"]) == {"cam", "lidar"}


def test_the_order_of_the_sensors_flips_the_sign(signals) -> None:
    camera, lidar = signals
    forward, backward = solve_time_offset(camera, lidar), solve_time_offset(lidar, camera)
    assert abs(forward.offset_s + backward.offset_s) < 0.5e-3, (forward.offset_s, backward.offset_s)


def test_a_board_that_does_not_turn_is_refused_naming_the_sensor(recording, signals) -> None:
    camera, _ = signals
    poses = np.tile(np.eye(4), (len(camera.t_s), 1, 1))
    poses[:, 2, 3] = 2.0  # 2 m ahead, facing the camera squarely all along
    still = board_normal_signal("cam2", camera.t_s, poses)
    with pytest.raises(InputError, match="cam2: the board's normal turned at most 0.0 deg"):
        solve_time_offset(camera, still)


def test_signals_that_cannot_be_compared_are_refused(signals) -> None:
    camera, _ = signals
    rates = MotionSignal("imu", "rates", camera.t_s, camera.vectors)
    with pytest.raises(InputError, match="cam gives directions and imu gives rates"):
        solve_time_offset(camera, rates)
    later = MotionSignal("lidar", "directions", camera.t_s + 100.0, camera.vectors)
    with pytest.raises(InputError, match="do not overlap in time within ±0.5 s"):
        solve_time_offset(camera, later)
    with pytest.raises(InputError, match="too few|at least 20"):
        MotionSignal("cam", "directions", camera.t_s[:5], camera.vectors[:5])
    with pytest.raises(InputError, match="max_offset_s"):
        TimeOffsetSettings(max_offset_s=0.0)


def test_the_command_reads_detections_and_a_folder_of_scans(tmp_path, recording) -> None:
    """``calib-studio time-offset --camera camera.yaml --detections corners.csv --scans DIR --board SPEC --init T``."""
    args = command_files(tmp_path, recording, recording.scan_t_s, recording.scans, recording.T_camera_lidar)
    run = cli_in_process(*args, "--init", tmp_path / "T.txt")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert abs(summary["time_offset_s"] - recording.offset_s) < 2e-3, summary
    assert set(summary) >= {"time_offset_s", "std", "R_a_b", "verdict", "seconds"}
    assert summary["std"]["time_s"] > 0 and "verdict:" in run.stderr

    missing = cli_in_process(*args)
    assert missing.returncode != 0 and "give --init or --init-xyzypr" in missing.stderr, missing.stderr
    (tmp_path / "scans" / "later.npy").write_bytes(b"")
    named = cli_in_process(*args, "--init", tmp_path / "T.txt")
    assert named.returncode != 0 and "later.npy" in named.stderr, named.stderr
