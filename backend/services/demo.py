"""The built-in demo session: the simulated rig, ready to explore in seconds.

The session's rig is the mounting a user first types in (:func:`~backend.sim.demo_rig.measured_demo_rig`:
``lidar_top`` and ``sweep_3d`` from the drawing, the others tape-measured, 2-5 cm and 1-3 deg off the
simulator's truth) with the camera intrinsics removed; the truth is ``truth.json`` beside it (:func:`frame_truth`),
so each accept visibly moves its sensors towards it. ``cam_front`` already carries the views step 3's
auto-capture keeps while the board is waved in front of it, up to full coverage, and their accepted solve
(``trusted``, so step 3 opens on "enough data"), so every screen has something to show. ``cam_wide`` is left
for the user to calibrate live.

For LiDAR-to-camera calibration, ``cam_front`` and ``lidar_top`` then watch the board
carried about the yard (:data:`PAIR_BOARD_POSES` poses, each held still for
:data:`PAIR_HOLD_S` seconds, the same for both), and the session holds
:data:`DEMO_PAIRS` image + cloud pairs of them to solve from.

For the multi-camera rig, ``cam_front`` and its stereo partner ``cam_right`` photograph the
same board poses: the session holds :data:`DEMO_SETS` synchronised sets of them, and both stay
on the shared hold clock so more sets can be captured live. ``cam_right`` has no intrinsics:
the joint solve estimates them with the rig.

Building it takes about half a minute on two cores (rendering about 110 frames, detecting the board in about 80,
a solve), so the session is built in a staging folder (:data:`STAGING_DIR`) and moved into place whole: a build
that is interrupted never leaves a half-built ``demo`` behind. :func:`start_demo_build` runs the build as a job, so a
server can serve its page at once and open the demo when it is ready.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from backend.calib._session import session_board
from backend.calib.board.coverage import Coverage
from backend.calib.board.detection import detect_board
from backend.calib.board.live_detection import LiveDetector
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.intrinsics.solver import IntrinsicsSettings
from backend.calib.lidar_camera.capture import store_pair
from backend.calib.multicam.capture import capture_set
from backend.calib.rig import service as rig_service
from backend.calib.rig.sensor_edits import SensorEdit
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Rig
from backend.devices.base import CaptureDevice, Sample, create_device
from backend.services.jobs import Job, JobRunner
from backend.services.live_capture import worth_keeping
from backend.sim.demo_rig import DEMO_BOARD, demo_rig, measured_demo_rig
from backend.sim.lidar_scene import ROBOT_PLACES, is_robot_place
from backend.store.atomic import write_json_atomic
from backend.store.session import Session, SessionStore

DEMO_NAME = "demo"
DEMO_CAMERA = "cam_front"
WAVE_FRAMES = 150
"""Frames of the simulated wave the demo follows at most for :data:`DEMO_CAMERA`'s views: one cycle of its board,
which reaches every part of the image."""
DEMO_LIDAR = "lidar_top"
DEMO_PAIRS = 20
PAIR_BOARD_POSES = 20
PAIR_HOLD_S = 3.0
CARRY_S = 2.0
"""Seconds the simulated person takes to carry the board on from one of the demo's poses to the next when it is
``carried`` (without stopping, for lining clocks up)."""
DEMO_SET_CAMERAS = ["cam_front", "cam_right"]
DEMO_SETS = 10
DEMO_SET_TOLERANCE_S = 5.0
TRUTH_FILE = "truth.json"
"""A demo session's simulator truth, ``{"frames": {name: T_root_frame (4x4, m)}, ...}``: the rig step shows each
frame's distance from it (only a demo has one)."""
STAGING_DIR = ".demo-building"
"""Folder under the sessions root where the demo is built before it is moved into place (not a session)."""
BUILD_TITLE = "preparing the demo session"


def frame_truth(session: Session) -> dict[str, np.ndarray]:
    """Each frame's true ``T_root_frame`` (4x4, m) from the session's :data:`TRUTH_FILE` (a demo's); empty for a
    session without one, or whose truth cannot be read (a real rig has no truth to show)."""
    try:
        frames = json.loads((session.path / TRUTH_FILE).read_text()).get("frames", {})
        return {str(name): np.array(T, dtype=float).reshape(4, 4) for name, T in frames.items()}
    except (OSError, ValueError, AttributeError, TypeError):
        return {}


def _retire(store: SessionStore, name: str) -> None:
    """Move an old demo session aside (never delete what a user may have captured)."""
    old = store.root / name
    if old.exists():
        old.rename(store.root / f"{name}-old-{time.strftime('%Y%m%d-%H%M%S')}")


def ensure_staged_session(store: SessionStore, name: str, staging_dir: str, build: Callable[[SessionStore], Session],
                          *, fresh: bool = False) -> Session:
    """Open the session ``name``, building it if missing (or ``fresh``: the old one is moved aside, never deleted).

    ``build`` creates it in a store at ``staging_dir`` under ``store.root``, and the finished session is renamed
    into place whole, so a build that is interrupted never leaves a half-built session behind.
    """
    if fresh:
        _retire(store, name)
    if (store.root / name).exists():
        return store.get(name)
    staging = store.root / staging_dir
    if staging.exists():  # left by an interrupted build: only the simulator's frames, nothing of a user's
        shutil.rmtree(staging)
    build(SessionStore(staging))
    (staging / name).rename(store.root / name)
    staging.rmdir()
    return store.get(name)


def ensure_demo_session(store: SessionStore, *, fresh: bool = False,
                        progress: ProgressCallback = no_progress) -> Session:
    """Open the demo session, building it from the simulator in :data:`STAGING_DIR` if missing (or ``fresh``).

    ``progress`` hears the whole build's fraction (0..1) and what it is doing.
    """
    return ensure_staged_session(store, DEMO_NAME, STAGING_DIR, lambda staging: _build(staging, progress),
                                 fresh=fresh)


def start_demo_build(store: SessionStore, jobs: JobRunner, *, fresh: bool = False) -> Job:
    """:func:`ensure_demo_session` as a job titled :data:`BUILD_TITLE` (its result: the demo :class:`Session`)."""
    return jobs.submit(BUILD_TITLE, lambda progress: ensure_demo_session(store, fresh=fresh, progress=progress))


def _build(store: SessionStore, progress: ProgressCallback) -> Session:
    """Create the demo session in ``store``, its rig as first measured (:func:`measured_demo_rig`) and the
    simulator's truth beside it (:data:`TRUTH_FILE`): the views of :data:`DEMO_CAMERA` that step 3's auto-capture
    keeps (:func:`_auto_captured_views`) and their accepted solve, then the pairs and the sets."""
    rig = measured_demo_rig()
    for camera in rig.sensors("camera"):
        camera.intrinsics = None
    session = store.create(DEMO_NAME, rig=rig, board=DEMO_BOARD, title="Simulated rig (known ground truth)")
    truth = demo_rig()
    write_json_atomic(session.path / TRUTH_FILE,
                      {"frames": {frame.name: truth.T_root_frame(frame.name).tolist() for frame in truth.sensors()}})
    board = session_board(session)
    with create_device(session.rig.get(DEMO_CAMERA).device) as device:
        samples = _auto_captured_views(device, board, lambda f, m: progress(0.1 * f, m))
        name = device.describe()
    with ThreadPoolExecutor(max_workers=2) as pool:  # OpenCV releases the GIL while detecting
        detections = []
        for i, detection in enumerate(pool.map(lambda sample: detect_board(sample.image, board), samples)):
            progress(0.1 + 0.1 * i / len(samples), f"detecting the board in the views of {DEMO_CAMERA}")
            detections.append(detection)
    for sample, detection in zip(samples, detections, strict=True):
        if detection is not None:
            intrinsics_service.store_capture(session, DEMO_CAMERA, sample.image, detection, device=name,
                                             timestamp_s=sample.timestamp_s, meta=sample.storable_meta())
    result_id, _ = intrinsics_service.solve_session(session, DEMO_CAMERA, IntrinsicsSettings(),
                                                    progress=lambda f, m: progress(0.2 + 0.1 * f, m))
    # The demo stands in for a user who read the verdict: a 'check' (e.g. too few views in the image corners) is
    # taken as it is and the confirmation recorded; a 'reject' is still refused.
    rig_service.accept(session, result_id, confirm=True)
    _add_board_pairs(session, lambda f, m: progress(0.3 + 0.3 * f, m))
    _add_camera_sets(session, lambda f, m: progress(0.6 + 0.4 * f, m))
    return session


def _auto_captured_views(device: CaptureDevice, board: BoardSpec, progress: ProgressCallback) -> list[Sample]:
    """The frames step 3's auto-capture keeps while the board is waved in front of ``device``, until the
    coverage is full (or :data:`WAVE_FRAMES` frames have passed): the live detector finds the board, and a frame
    is kept by auto-capture's own rule (:func:`~backend.services.live_capture.worth_keeping`). Their full-accuracy
    detection is left to the caller, which runs it on both cores."""
    detector = LiveDetector(board)
    coverage: Coverage | None = None
    kept: list[Sample] = []
    for i in range(WAVE_FRAMES):
        progress(i / WAVE_FRAMES, f"following the board waved in front of {DEMO_CAMERA} ({len(kept)} views kept)")
        sample = device.read()
        detection = detector.detect(sample.image)
        if not worth_keeping(coverage, detection):
            continue
        coverage = coverage or Coverage(board, detection.image_size)
        coverage.add(detection)
        kept.append(sample)
        if coverage.full:
            break
    return kept


def _add_board_pairs(session: Session, progress: ProgressCallback) -> None:
    """Point ``cam_front`` and ``lidar_top`` at the board carried about the yard, and store :data:`DEMO_PAIRS`
    pairs of theirs: frame ``i`` of each sees board pose ``i`` (read in step, so no waiting for the board)."""
    camera_settings = yard_board(session.rig.get(DEMO_CAMERA).device, hold_s=0.0)
    lidar_settings = {**session.rig.get(DEMO_LIDAR).device, "board_poses": PAIR_BOARD_POSES}
    board = session_board(session)
    with create_device(camera_settings) as camera, create_device(lidar_settings) as lidar:
        device = f"{camera.describe()} + {lidar.describe()}"
        for i in range(DEMO_PAIRS):
            progress(i / DEMO_PAIRS, f"storing simulated pairs of {DEMO_CAMERA} and {DEMO_LIDAR}")
            image = camera.read()
            store_pair(session, DEMO_CAMERA, DEMO_LIDAR, image, lidar.read(), device=device,
                       detection=detect_board(image.image, board))
    session.set_device(DEMO_CAMERA, camera_settings | {"board_hold_s": PAIR_HOLD_S})
    session.set_device(DEMO_LIDAR, lidar_settings | {"board_hold_s": PAIR_HOLD_S})


def _add_camera_sets(session: Session, progress: ProgressCallback) -> None:
    """Store :data:`DEMO_SETS` synchronised sets of :data:`DEMO_SET_CAMERAS` photographing the same board poses in
    the yard (both read at once, frame ``i`` seeing pose ``i``), and leave both on the shared hold clock."""
    settings = {name: yard_board(session.rig.get(name).device, hold_s=0.0) for name in DEMO_SET_CAMERAS}
    with contextlib.ExitStack() as stack:
        devices = {name: stack.enter_context(create_device(settings[name])) for name in DEMO_SET_CAMERAS}
        described = " + ".join(device.describe() for device in devices.values())
        for i in range(DEMO_SETS):
            progress(i / DEMO_SETS, f"storing simulated sets of {', '.join(DEMO_SET_CAMERAS)}")
            # Frame i of each device sees pose i whenever it is read, so the stamps need not be close: a busy
            # machine may start one render a little after the other.
            capture_set(session, DEMO_SET_CAMERAS, {name: device.read for name, device in devices.items()},
                        device=described, tolerance_s=DEMO_SET_TOLERANCE_S)
    for name in DEMO_SET_CAMERAS:
        session.set_device(name, settings[name] | {"board_hold_s": PAIR_HOLD_S})


BOARD_MOTIONS = {"wave": "waved close in front of it, all over the image (for its lens)",
                 "scene": "carried about the yard 2-3 m ahead, held still at each place (for the rig)",
                 "carried": f"carried about the yard 2-3 m ahead without stopping, {CARRY_S:g} s from each place to "
                            "the next (for clocks)"}
"""What the simulated person does with the board for a simulated camera (its device's ``board_motion``, and
``board_carry_s`` above 0 when ``carried``)."""
YARD_CLOCK_KEYS = ("board_hold_s", "board_carry_s")
"""The settings of a simulated device that say when the yard's board is where."""


def _yard_clock(motion: str) -> dict:
    """The hold and carry settings of every simulated device seeing the yard's board for ``motion`` (``scene`` or
    ``carried``)."""
    return {"board_hold_s": 0.0, "board_carry_s": CARRY_S} if motion == "carried" else {"board_hold_s": PAIR_HOLD_S}


def yard_board(device: dict, hold_s: float = PAIR_HOLD_S) -> dict:
    """A simulated camera's ``device`` with the board carried about the yard: the demo's :data:`PAIR_BOARD_POSES`
    poses (the ones a ``simulated_lidar`` with as many ``board_poses`` sees), each held ``hold_s`` (s) on the clock
    every simulated device shares (0: the pose advances every frame)."""
    device = {key: value for key, value in device.items() if key not in YARD_CLOCK_KEYS}
    return {**device, "board_motion": "scene", "n_poses": PAIR_BOARD_POSES, "board_hold_s": hold_s}


def simulated_board_motion(session: Session, camera: str) -> str | None:
    """What the simulated person does with the board for ``camera`` (a key of :data:`BOARD_MOTIONS`) when it is a
    simulated camera, else None."""
    device = session.rig.get(camera).device
    if device.get("driver") != "simulated":
        return None
    return "carried" if device.get("board_carry_s", 0) > 0 else device.get("board_motion", "wave")


def move_simulated_board(session: Session, camera: str, motion: str) -> rig_service.SensorChange:
    """Have the simulated person handle the board as ``motion`` says for ``camera`` (a simulated camera's device
    edit, probed and saved like any): ``wave`` for step 3's lens calibration, ``scene`` (the demo's pair and set
    poses, on the hold clock every simulated device shares) for steps 6 and 7, ``carried`` (through the same poses
    without stopping) for step 11's clocks. ``scene`` and ``carried`` concern the one board in the yard: every
    simulated device seeing it (cameras with the ``scene`` motion, LiDARs with ``board_poses``) is put on the same
    clock, in one saved change. :class:`InputError` naming the camera when it is not simulated."""
    if motion not in BOARD_MOTIONS:
        raise InputError(f"board motion {motion!r}: expected one of {', '.join(BOARD_MOTIONS)}", "motion")
    if simulated_board_motion(session, camera) is None:
        raise InputError(f"{camera} is not a simulated camera: its board is moved by a person, not the studio",
                         camera)
    device = {key: value for key, value in session.rig.get(camera).device.items()
              if key not in ("board_motion", "n_poses", *YARD_CLOCK_KEYS)}
    if motion == "wave":
        return rig_service.edit_sensor(session, camera, SensorEdit(device=device | {"board_motion": "wave"}))
    clock = _yard_clock(motion)
    change = rig_service.edit_sensor(session, camera, SensorEdit(device=yard_board(device) | clock))

    def same_clock(rig: Rig) -> None:
        for frame in rig.sensors():
            settings = frame.device
            if frame.name == camera or not isinstance(settings, dict):
                continue
            if (settings.get("driver") == "simulated" and settings.get("board_motion") == "scene") or (
                    settings.get("driver") == "simulated_lidar" and settings.get("board_poses", 0) > 0):
                for key in YARD_CLOCK_KEYS:
                    settings.pop(key, None)
                settings.update(clock)

    session.edit_rig(same_clock)
    return change


ROBOT_PLACE_NAMES = [f"x {x:+.1f} m, y {y:+.1f} m, heading {heading:+.0f}°" + (" (the yard's origin)" if not i else "")
                     for i, (x, y, heading) in enumerate(ROBOT_PLACES)]
"""How the studio names each of the :data:`ROBOT_PLACES` (``base_link`` in the yard's frame)."""


def _yard_settings(device: object) -> dict | None:
    """The settings that place a simulator of the yard (``place`` lives there): the device's own for a simulated
    camera or LiDAR, its scanner's for a swept scanner with a simulated head; None for any other device (a real
    one, a recording, the depth cell, none)."""
    if not isinstance(device, dict):
        return None
    if device.get("driver") in ("simulated", "simulated_lidar"):
        return device
    scanner = device.get("scanner")
    if device.get("driver") == "swept_scanner" and isinstance(scanner, dict) and scanner.get("driver") == "sim":
        return scanner
    return None


def simulated_place(session: Session) -> int | None:
    """Where the session's simulated robot stands in the yard (an index of :data:`ROBOT_PLACES`), or None when
    none of its sensors is a simulator of the yard."""
    placed = (_yard_settings(frame.device) for frame in session.rig.sensors())
    return next((settings.get("place", 0) for settings in placed if settings is not None), None)


def move_simulated_robot(session: Session, place: int) -> list[str]:
    """Drive the simulated robot to ``place`` of the yard (:data:`ROBOT_PLACES`): every simulated camera and
    LiDAR of the session (the swept scanner's head included) sees the yard from there, with the board carried
    about in front of it, so captures taken there are a scene of their own. Devices already open keep their place
    until they are opened again. One saved change; returns the sensors moved. :class:`InputError` naming ``place``
    for a place that is not one of them, or for a session without simulated sensors."""
    if not is_robot_place(place):
        raise InputError(f"place {place!r}: expected one of 0-{len(ROBOT_PLACES) - 1} (where the simulated robot "
                         "can stand in the yard)", "place")
    moved = []

    def drive(rig: Rig) -> None:
        for frame in rig.sensors():
            settings = _yard_settings(frame.device)
            if settings is not None:
                settings["place"] = place
                moved.append(frame.name)
        if not moved:
            raise InputError("the session has no simulated sensors: a real robot is moved by its crew", "place")

    session.edit_rig(drive)
    return moved
