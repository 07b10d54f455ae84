"""The servo-scanner demo: a Hokuyo UTM-30LX-EW nodded by a Dynamixel servo, a camera on a pan head on top, and the
rig's board seen by both at three pan positions (:mod:`backend.sim.servo_scanner`).

``calib-studio demo --rig servo-scanner`` opens the session :data:`SERVO_SCANNER_NAME`:

- its rig: ``sweep_hokuyo`` (the swept scanner, its frame the servo's mount) where the drawing puts it, and
  ``cam_top`` on it, tape-measured (:func:`~backend.sim.tape_measure.tape_guess`: 2-5 cm, 1-3 deg off the truth at pan
  reading 0), its intrinsics already calibrated (the simulator's), so the LiDAR-camera solves can start at once;
- ``sweep_hokuyo``'s device is the Hokuyo driver on the swept-scanner driver, both talking to byte-level simulators
  (SCIP 2.0 over TCP on 127.0.0.1, Dynamixel Protocol 2.0 on a pty); its sweep geometry is the calibrated one (step
  5's job, done: the simulator's truth), and its simulated head holds the board (:func:`sweep_device`);
- the session's board is the rig's ``checkerboard:8x6:0.057`` (7 x 9 squares of 57 mm);
- :data:`PAIRS` image + sweep pairs of it: the camera at the left, the centre and the right (pan readings +45, 0,
  -45 deg, kept as each image's ``pan_rad``), six placements of the board before the centre and four before each
  side, each swept through the :data:`~backend.sim.servo_scanner.SWEEP_STEPS` servo steps that hold the boards
  (-41..25 deg of the rig's -90..90: a whole sweep of 173 steps takes almost three times as long);
- the simulator's truth is ``truth.json`` beside the session (:data:`~backend.services.demo.TRUTH_FILE`): each frame's
  ``T_root_frame`` (``cam_top`` at pan reading 0), the sweep geometry, the pan axis in ``sweep_hokuyo``'s frame, and
  every pair's board pose (by image capture id).

The sweeps run through the real drivers and simulators, a servo step and a 25 ms scan at a time, three at once
(:data:`SWEEP_WORKERS`: each waits on its simulators' clocks) while the camera's photographs of the yard are
rendered. About 15-20 s on two cores. The session is built in a staging folder and moved into place whole
(:func:`~backend.services.demo.ensure_staged_session`), as a job (:func:`start_servo_scanner_build`).
"""

from __future__ import annotations

import copy
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from backend.calib.board.detection import detect_board
from backend.calib.lidar_camera.capture import store_pair
from backend.calib.lidar_camera.sweep_corners_service import PAN_META_KEY
from backend.core.boards import BoardSpec
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Frame, Rig
from backend.devices.base import Sample, create_device
from backend.services.demo import TRUTH_FILE, ensure_staged_session
from backend.services.jobs import Job, JobRunner
from backend.sim.demo_rig import CAD_SIGMA, TAPE_ERROR_DEG, TAPE_ERROR_M
from backend.sim.servo_scanner import (
    BOARD,
    CAMERA,
    NODDING,
    PAN_AXIS,
    PAN_POINT,
    PAN_POSITIONS_DEG,
    SERVO_STEP_DEG,
    SWEEP_START_DEG,
    SWEEP_STEPS,
    T_BASE_MOUNT,
    T_MOUNT_CAMERA,
    camera_image,
    placements,
)
from backend.sim.tape_measure import tape_guess
from backend.store.atomic import write_json_atomic
from backend.store.session import Session, SessionStore

SERVO_SCANNER_NAME = "servo-scanner"
CAMERA_NAME = "cam_top"
LIDAR_NAME = "sweep_hokuyo"
STAGING_DIR = ".servo-scanner-building"
"""Folder under the sessions root where the session is built before it is moved into place (not a session)."""
BUILD_TITLE = "preparing the servo-scanner session"
TAPE_SEED = 22
SWEEP_WORKERS = 3
"""Sweeps run at once: each mostly waits for its simulated servo to settle and its simulated scanner to turn."""
PAIRS = sum(len(placements(position)) for position in PAN_POSITIONS_DEG)
CAMERA_DEVICE = "servo-scanner simulator: camera"


def sweep_device(T_base_board: np.ndarray, seed: int = 0) -> dict:
    """``sweep_hokuyo``'s device: the Hokuyo driver (``host="sim"``) on the swept-scanner driver (``servo_port="sim"``)
    through the steps that hold the boards, assembled with the calibrated geometry; the simulated head on the horn
    is the rig's truth, with the board at ``T_base_board`` (4x4, m) and its range noise seeded by ``seed``."""
    head = {"geometry": NODDING.to_dict(), "T_base_mount": T_BASE_MOUNT.tolist(), "board": BOARD,
            "board_pose": np.asarray(T_base_board).tolist(), "seed": seed}
    return {"driver": "swept_scanner", "servo_port": "sim", "steps": SWEEP_STEPS, "start_deg": SWEEP_START_DEG,
            "end_deg": SWEEP_START_DEG + SERVO_STEP_DEG * (SWEEP_STEPS - 1), "geometry": NODDING.to_dict(),
            "scanner": {"driver": "hokuyo", "host": "sim", "sim": head}}


def measured_rig() -> Rig:
    """The rig as first typed in: the swept scanner's mount as drawn, the camera on it tape-measured (seeded) with
    its intrinsics known, both with their devices."""
    rig = Rig("base_link")
    rig.add(Frame(LIDAR_NAME, "base_link", T_BASE_MOUNT, kind="lidar3d", mount_sigma=CAD_SIGMA,
                  device=sweep_device(placements("centre")[0])))
    guess = tape_guess(T_MOUNT_CAMERA, np.random.default_rng(TAPE_SEED), TAPE_ERROR_M, TAPE_ERROR_DEG)
    rig.add(Frame(CAMERA_NAME, LIDAR_NAME, guess, kind="camera", intrinsics=copy.deepcopy(CAMERA)))
    return rig


def ensure_servo_scanner_session(store: SessionStore, *, fresh: bool = False,
                                 progress: ProgressCallback = no_progress) -> Session:
    """Open the servo-scanner session, building it from the simulators in :data:`STAGING_DIR` if missing (or
    ``fresh``: the old one is moved aside, never deleted). ``progress`` hears the build's fraction (0..1)."""
    return ensure_staged_session(store, SERVO_SCANNER_NAME, STAGING_DIR, lambda staging: _build(staging, progress),
                                 fresh=fresh)


def start_servo_scanner_build(store: SessionStore, jobs: JobRunner, *, fresh: bool = False) -> Job:
    """:func:`ensure_servo_scanner_session` as a job titled :data:`BUILD_TITLE` (its result: the :class:`Session`)."""
    return jobs.submit(BUILD_TITLE, lambda progress: ensure_servo_scanner_session(store, fresh=fresh,
                                                                                  progress=progress))


def _sweep(T_base_board: np.ndarray, seed: int) -> Sample:
    """One sweep of the board at ``T_base_board`` through the drivers and their simulators."""
    with create_device(sweep_device(T_base_board, seed)) as device:
        return device.read()


def _build(store: SessionStore, progress: ProgressCallback) -> Session:
    """Create the session in ``store``: the rig, the truth beside it, and the pairs (sweeps and photographs)."""
    session = store.create(SERVO_SCANNER_NAME, rig=measured_rig(), board=BOARD,
                           title="Simulated servo-scanner rig: Hokuyo on a Dynamixel, camera on a pan head "
                                 "(known ground truth)")
    board = BoardSpec.parse(BOARD)
    shots = [(math.radians(pan_deg), T_base_board) for position, pan_deg in PAN_POSITIONS_DEG.items()
             for T_base_board in placements(position)]
    with ThreadPoolExecutor(max_workers=SWEEP_WORKERS) as pool:
        sweeps = [pool.submit(_sweep, T_base_board, k) for k, (_, T_base_board) in enumerate(shots)]
        images = []
        for k, (pan_rad, T_base_board) in enumerate(shots):  # rendered while the sweeps run
            progress(0.5 * k / len(shots), f"photographing the board at pan {math.degrees(pan_rad):+.0f} deg")
            image = camera_image(T_base_board, pan_rad, k)
            images.append((image, detect_board(image, board)))
        placed = {}
        for k, ((pan_rad, T_base_board), sweep, (image, detection)) in enumerate(zip(shots, sweeps, images,
                                                                                     strict=True)):
            progress(0.5 + 0.5 * k / len(shots), f"sweeping the board with {LIDAR_NAME} ({k + 1} of {len(shots)})")
            pair = store_pair(session, CAMERA_NAME, LIDAR_NAME,
                              Sample(float(k), image=image, meta={PAN_META_KEY: pan_rad}), sweep.result(),
                              device=f"{CAMERA_DEVICE} + {LIDAR_NAME} simulator", detection=detection)
            placed[pair.image.id] = {"pan_deg": math.degrees(pan_rad), "T_base_board": T_base_board.tolist()}
    T_base_camera = T_BASE_MOUNT @ T_MOUNT_CAMERA
    write_json_atomic(session.path / TRUTH_FILE, {
        "frames": {LIDAR_NAME: T_BASE_MOUNT.tolist(), CAMERA_NAME: T_base_camera.tolist()},
        "sweep_geometry": NODDING.to_dict(),
        "pan_axis": {"frame": LIDAR_NAME, "axis": PAN_AXIS.tolist(), "axis_point_m": PAN_POINT.tolist()},
        "placements": placed})
    return session
