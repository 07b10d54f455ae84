"""The built-in demo session: the simulated rig, ready to explore in seconds.

The session's rig is the simulator's ground-truth mounting with the camera
intrinsics removed (the simulator keeps the truth), and ``cam_front`` already
carries captures and an accepted intrinsics solve so every screen has something
to show. ``cam_wide`` is left for the user to calibrate live.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

from backend.devices.base import create_device
from backend.services import intrinsics as intrinsics_service
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.solvers.board_detection import detect_board
from backend.solvers.intrinsics import IntrinsicsSettings
from backend.solvers.result import ProgressCallback, no_progress
from backend.store.session import Session, SessionStore

DEMO_NAME = "demo"
DEMO_CAMERA = "cam_front"
DEMO_VIEWS = 15


def _retire(store: SessionStore, name: str) -> None:
    """Move an old demo session aside (never delete what a user may have captured)."""
    old = store.root / name
    if old.exists():
        old.rename(store.root / f"{name}-old-{time.strftime('%Y%m%d-%H%M%S')}")


def ensure_demo_session(store: SessionStore, *, fresh: bool = False, views: int = DEMO_VIEWS,
                        progress: ProgressCallback = no_progress) -> Session:
    """Open the demo session, building it from the simulator if missing (or ``fresh``).

    The simulator's board poses are already spread over the image, so the first
    ``views`` frames are kept as they come; detection runs on both cores.
    """
    if fresh:
        _retire(store, DEMO_NAME)
    if (store.root / DEMO_NAME).exists():
        return store.get(DEMO_NAME)
    rig = demo_rig()
    for camera in rig.sensors("camera"):
        camera.intrinsics = None
    session = store.create(DEMO_NAME, rig=rig, board=DEMO_BOARD, title="Simulated rig (known ground truth)")
    board = intrinsics_service.session_board(session)
    with create_device(session.rig.get(DEMO_CAMERA).device) as device:
        samples = [device.read() for _ in range(views)]
        name = device.describe()
    with ThreadPoolExecutor(max_workers=2) as pool:  # OpenCV releases the GIL while detecting
        detections = list(pool.map(lambda sample: detect_board(sample.image, board), samples))
    for i, (sample, detection) in enumerate(zip(samples, detections, strict=True)):
        progress(i / views, f"storing simulated views of {DEMO_CAMERA}")
        if detection is not None:
            intrinsics_service.store_capture(session, DEMO_CAMERA, sample.image, detection, device=name,
                                             timestamp_s=sample.timestamp_s, meta={"frame_index": i})
    result_id, _ = intrinsics_service.solve_session(session, DEMO_CAMERA, IntrinsicsSettings(), progress=progress)
    intrinsics_service.accept(session, DEMO_CAMERA, result_id)
    return session
