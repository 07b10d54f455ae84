"""A session whose camera and 3D LiDAR captured a simulated board carried through both views
(:func:`backend.sim.moving_board.simulate_moving_board`), for the API's and the studio's time-offset tests. The
camera's captures hold the simulated detections; their images are blank, as the time offset reads the detections."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.calib.camera_imu.observations import format_detections_csv
from backend.core.rig import Frame, Rig
from backend.exports.ros_camera_info import write_camera_info
from backend.sim.moving_board import BOARD, CAMERA, MovingBoardRecording
from backend.store.session import Session, SessionStore


def moving_board_session(store: SessionStore, recording: MovingBoardRecording, name: str = "rig") -> Session:
    """Session ``name`` with cameras ``cam`` (the recording's) and ``cam2`` (no captures) and the LiDAR ``lidar``
    mounted on ``cam`` by the true ``T_camera_lidar``."""
    rig = Rig()
    rig.add(Frame("cam", "base_link", kind="camera", intrinsics=CAMERA))
    rig.add(Frame("lidar", "cam", recording.T_camera_lidar, kind="lidar3d"))
    rig.add(Frame("cam2", "base_link", kind="camera", intrinsics=CAMERA))
    session = store.create(name, rig=rig, board=BOARD)
    blank = np.full((CAMERA.height, CAMERA.width), 128, np.uint8)
    for t_s, detection in zip(recording.camera_t_s, recording.detections, strict=True):
        session.add_capture("cam", blank, {"timestamp_s": float(t_s), "device": "sim", "board": BOARD,
                                           "detection": detection.to_dict()})
    for t_s, points in zip(recording.scan_t_s, recording.scans, strict=True):
        session.add_cloud_capture("lidar", points, None, {"timestamp_s": float(t_s), "device": "sim"})
    return session


def scanner_session(store: SessionStore, recording: MovingBoardRecording, name: str = "rig") -> Session:
    """:func:`moving_board_session` with the recording's 2D scanner ``scanner`` too (kind ``lidar2d``), mounted on
    ``cam`` by the true ``T_camera_scanner``, and its scans."""
    session = moving_board_session(store, recording, name)
    session.add_sensor(Frame("scanner", "cam", recording.T_camera_scanner, kind="lidar2d"))
    for t_s, points in zip(recording.scanner_t_s, recording.scanner_scans, strict=True):
        session.add_cloud_capture("scanner", points, None, {"timestamp_s": float(t_s), "device": "sim"})
    return session


def command_files(folder: Path, recording: MovingBoardRecording, scan_t_s: np.ndarray, scans: list[np.ndarray],
                  T_camera_scans: np.ndarray) -> list:
    """Write what ``calib-studio time-offset`` reads into ``folder`` (the camera's camera_info, its corners as CSV, the
    clouds named by their stamps in ns, the initial transform as ``T.txt``); the command's arguments but ``--init``."""
    write_camera_info(folder / "camera.yaml", recording.camera, "cam")
    (folder / "corners.csv").write_bytes(format_detections_csv(recording.observations()))
    (folder / "scans").mkdir()
    for t_s, points in zip(scan_t_s, scans, strict=True):
        np.save(folder / "scans" / f"{round(t_s * 1e9)}.npy", points)
    np.savetxt(folder / "T.txt", T_camera_scans)
    return ["time-offset", "--camera", folder / "camera.yaml", "--detections", folder / "corners.csv", "--scans",
            folder / "scans", "--board", BOARD, "--json"]
