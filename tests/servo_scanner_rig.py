"""The servo-scanner demo session for the tests of its solves (service, API, CLI, studio): built once per run from
the byte-level simulators (:func:`backend.services.demo_servo_scanner.ensure_servo_scanner_session`, shared by every
test process through :func:`tests.conftest.built_once`) and copied per test module, with its truth; and a pair whose
board stands too far for its corners, the bad input each front-end must name."""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.lidar_camera.capture import CapturePair, store_pair
from backend.calib.lidar_camera.sweep_corners_service import PAN_META_KEY
from backend.core.boards import BoardSpec
from backend.core.transforms import invert
from backend.devices.base import Sample
from backend.services.demo import TRUTH_FILE
from backend.services.demo_servo_scanner import CAMERA_NAME, LIDAR_NAME, ensure_servo_scanner_session
from backend.sim.lidar_scene import LidarScene
from backend.sim.servo_scanner import BOARD, NODDING, T_BASE_MOUNT, board_placement, camera_image, sweep_angles_rad
from backend.sim.swept_head import static_sweep
from backend.store.session import Session, SessionStore
from tests.conftest import built_once

FAR_PLACEMENT = (2.6, 0.0, 0.8, 0, 0, 0)
"""A board 2.25 m from the mount: its squares span about 1.4 servo steps, too few for its corners."""


def _build(root: Path) -> None:
    started = time.perf_counter()
    ensure_servo_scanner_session(SessionStore(root))
    print(f"servo-scanner session built in {time.perf_counter() - started:.1f} s", file=sys.stderr)


def servo_scanner_sessions(tmp_path_factory: pytest.TempPathFactory, folder: str) -> Path:
    """A sessions folder of the module's own holding a copy of the run's servo-scanner session."""
    template = built_once(tmp_path_factory, "servo_scanner_template", _build)
    sessions = tmp_path_factory.mktemp(folder) / "sessions"
    shutil.copytree(template, sessions)
    return sessions


def truth(session: Session) -> dict:
    """The session's ``truth.json``."""
    return json.loads((session.path / TRUTH_FILE).read_text())


def true_T_camera_lidar(session: Session) -> np.ndarray:
    """``T_camera_lidar`` (4x4, m) of the truth: ``cam_top`` at pan reading 0 in ``sweep_hokuyo``'s frame."""
    frames = truth(session)["frames"]
    return invert(np.array(frames[CAMERA_NAME])) @ np.array(frames[LIDAR_NAME])


def store_far_pair(session: Session) -> CapturePair:
    """Store a pair whose board stands too far for its corners in the sweep (:data:`FAR_PLACEMENT`; the camera still
    finds it): a sweep ray-cast at the servo's readings exactly, kept as a swept capture is."""
    T_base_board = board_placement(FAR_PLACEMENT)
    scans = static_sweep(LidarScene(T_base_board, board=BOARD), T_BASE_MOUNT, NODDING, sweep_angles_rad(), seed=5)
    points, intensity, _ = NODDING.assemble(scans)
    sweep = Sample(time.time(), points=points, intensity=intensity, meta={
        "servo_angles_rad": [angle for angle, _, _ in scans], "step_counts": [len(p) for _, p, _ in scans],
        "geometry": NODDING.to_dict()})
    image = camera_image(T_base_board, 0.0, 99)
    return store_pair(session, CAMERA_NAME, LIDAR_NAME, Sample(time.time(), image=image, meta={PAN_META_KEY: 0.0}),
                      sweep, device="far board", detection=detect_board(image, BoardSpec.parse(BOARD)))

