"""The time offset between a camera and a 2D scanner (a YDLiDAR-like 8 Hz planar scanner beside a USB webcam) from a
board carried across the scan plane and turned about the vertical (simulated: 37 ms apart, each shot of the scanner
at its own instant): the board's line in the scan plane, as the scanner sees it and as the camera predicts it
through the rig's camera-scanner transform; the session path, the command, and the refusal of a board never turned
about the vertical."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.time_offset import service
from backend.calib.time_offset.board_signals import camera_board_poses
from backend.calib.time_offset.scan_line import (
    board_cuts,
    fit_sweep,
    planar_scans,
    scan_line_signals,
    scanner_lines,
)
from backend.calib.time_offset.solver import solve_time_offset
from backend.core.errors import InputError
from backend.core.rig import Frame
from backend.sim.moving_board import simulate_moving_board
from backend.store.session import SessionStore
from tests.conftest import cli_in_process
from tests.time_offset_session import command_files, scanner_session

OFFSET_S = 0.037
SCANNER_HZ = 8.0


@pytest.fixture(scope="module")
def recording():
    return simulate_moving_board(duration_s=18.0, seed=1, scanner_offset_s=OFFSET_S, scanner_hz=SCANNER_HZ)


@pytest.fixture(scope="module")
def poses(recording):
    return camera_board_poses(recording.camera, recording.board, recording.camera_t_s, recording.detections)


@pytest.fixture(scope="module")
def lines(recording, poses):
    """The camera's board cuts, the scanner's lines and the fitted sweep (s per rad)."""
    times, T_camera_boards = poses
    cuts = board_cuts(recording.board, times, T_camera_boards, recording.T_camera_scanner)
    scanner = scanner_lines("scanner", recording.board, recording.scanner_t_s, recording.scanner_scans, cuts,
                            recording.T_camera_scanner)
    return cuts, scanner, fit_sweep(cuts, "cam", scanner)


def test_camera_scanner_offset_within_2_ms_and_3_sigma(recording, lines) -> None:
    cuts, scanner, tau = lines
    assert len(scanner.t_s) > 0.95 * len(recording.scanner_scans) and cuts.upright.all()
    assert not np.any(scanner.vectors[:, 2]) and np.allclose(np.linalg.norm(scanner.vectors, axis=1), 1.0)
    result = solve_time_offset(cuts.signal("cam", tau), scanner)
    error_s = result.offset_s - OFFSET_S
    print(f"camera-scanner offset {1e3 * result.offset_s:.2f} ms (truth 37), sigma {1e3 * result.std_s:.2f} ms, "
          f"sweep {1e3 * tau:.2f} ms/rad, halves {result.halves.to_dict() if result.halves else None}")
    assert abs(error_s) < 2e-3 and abs(error_s) < 3 * result.std_s, (error_s, result.std_s)
    assert result.alignment.kind == "lines" and result.verdict.level == "trusted", result.verdict.reasons
    assert result.halves is not None and abs(result.halves.difference_s) < 3 * result.halves.expected_s
    # both lines are in the scanner's axes through the true mounting: the turn between them is nearly none
    turn_deg = np.degrees(Rotation.from_matrix(result.alignment.R_a_b).magnitude())
    assert turn_deg < 0.3 and np.allclose(result.alignment.R_a_b[2], [0, 0, 1]), result.alignment.R_a_b


def test_the_sweep_comes_back_as_the_scanners_turn(lines) -> None:
    """The simulated scanner turns clockwise (its time runs against anticlockwise azimuth) at 8 Hz: -19.9 ms/rad."""
    _, _, tau = lines
    expected = -1 / (2 * np.pi * SCANNER_HZ)
    assert 0.6 * abs(expected) < -tau < 1.4 * abs(expected), (tau, expected)


def test_a_board_not_turned_about_the_vertical_is_refused() -> None:
    still = simulate_moving_board(duration_s=8.0, seed=1, scanner_offset_s=OFFSET_S, yaw=False)
    times, T_camera_boards = camera_board_poses(still.camera, still.board, still.camera_t_s, still.detections)
    with pytest.raises(InputError, match=r"cam: the board's line in the 2D scanner's plane turned at most \d\.\d deg; "
                                         r"turn the board about a vertical axis \(yaw\)"):
        scan_line_signals("cam", "scanner", still.board, still.scanner_t_s, still.scanner_scans, times,
                          T_camera_boards, still.T_camera_scanner)


def test_scans_of_both_kinds_are_refused(recording) -> None:
    assert planar_scans(recording.scanner_scans, "scans") and not planar_scans(recording.scans, "scans")
    with pytest.raises(InputError, match="3 of 5 clouds have all their points at z = 0") as refused:
        planar_scans(recording.scanner_scans[:3] + recording.scans[:2], "scans/")
    assert refused.value.input == "scans/"


def test_the_session_lines_the_scanner_up_with_the_camera(tmp_path, recording) -> None:
    assert ("camera", "lidar2d") in service.PAIRS and "camera + 2D scanner" in service.SUPPORTED
    session = scanner_session(SessionStore(tmp_path / "sessions"), recording)
    record = session.result(service.solve_session(session, "cam", "scanner"))
    error_s = record["time_offset_s"] - OFFSET_S
    assert abs(error_s) < 2e-3 and abs(error_s) < 3 * record["std"]["time_s"], (error_s, record["std"])
    assert record["sensor_b"] == "scanner" and record["alignment"]["kind"] == "lines"
    assert record["verdict"]["level"] == "trusted", record["verdict"]
    with pytest.raises(InputError, match="name the camera first"):
        service.check_pair(session, "scanner", "cam")
    session.add_sensor(Frame("scanner_3d", "cam", recording.T_camera_lidar, kind="lidar2d"))
    for t_s, points in zip(recording.scan_t_s[:3], recording.scans[:3], strict=True):
        session.add_cloud_capture("scanner_3d", points, None, {"timestamp_s": float(t_s), "device": "sim"})
    with pytest.raises(InputError, match=r"scanner_3d is a 2D scanner \(lidar2d\) but its captures hold points off"):
        service.signals(session, "cam", "scanner_3d")


def test_the_command_takes_a_folder_of_planar_scans(tmp_path, recording) -> None:
    """``calib-studio time-offset ... --scans DIR`` where every cloud's points have z = 0: a 2D scanner's."""
    args = command_files(tmp_path, recording, recording.scanner_t_s, recording.scanner_scans,
                         recording.T_camera_scanner)
    run = cli_in_process(*args, "--init", tmp_path / "T.txt")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert set(summary) == {"sensor_a", "sensor_b", "time_offset_s", "std", "R_a_b", "samples", "verdict", "seconds"}
    assert abs(summary["time_offset_s"] - OFFSET_S) < 2e-3, summary
    assert summary["sensor_b"] == "lidar" and set(summary["std"]) == {"time_s", "rot_deg"}
    assert summary["verdict"]["level"] == "trusted" and "verdict:" in run.stderr
