"""A session whose camera and 3D LiDAR captured a simulated board carried through both views
(:func:`backend.sim.moving_board.simulate_moving_board`), for the API's and the studio's time-offset tests. The
camera's captures hold the simulated detections; their images are blank, as the time offset reads the detections."""

from __future__ import annotations

import numpy as np

from backend.core.rig import Frame, Rig
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
