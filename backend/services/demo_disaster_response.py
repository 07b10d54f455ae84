"""The disaster-response demo: the Blackfly and the Livox of :mod:`backend.sim.disaster_response`, a wall test field and
a V-target, ready to calibrate.

``calib-studio demo --rig disaster-response`` opens the session :data:`DISASTER_RESPONSE_NAME`:

- the rig as first measured: ``camera`` on ``base_link`` (its intrinsics unknown), ``livox`` on the camera at the
  tape-measured mounting (:data:`~backend.sim.disaster_response.MEASURED_MOUNT`, 3-5 cm and 2-3 deg off);
- the session's camera target is the wall test field (its survey kept as the session's ``survey.csv``), and its
  V-target the paper's 100 x 60 cm plates;
- ``camera`` holds the 12 test-field images (six positions, straight and turned 90 deg) and their accepted
  photogrammetric solve, so the LiDAR step can start at once (the intrinsics step shows it, and solves again on
  request);
- ``camera`` and ``livox`` hold the 18 V-target pairs (nine positions at two heights) to solve from;
- the simulator's truth is ``truth.json`` beside the session (:data:`~backend.services.demo.TRUTH_FILE`).

It is built in a staging folder and moved into place whole (:func:`~backend.services.demo.ensure_staged_session`),
as a job (:func:`start_disaster_response_build`); about 20 s on two cores (rendering 30 images and 18 clouds).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.intrinsics.solver import IntrinsicsSettings
from backend.calib.lidar_camera.capture import store_pair
from backend.calib.rig import service as rig_service
from backend.calib.test_field.detection import detect_test_field
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Frame, Rig
from backend.core.test_field import SESSION_SURVEY, TestField
from backend.core.v_target import VTarget
from backend.devices.base import Sample
from backend.services.demo import TRUTH_FILE, ensure_staged_session
from backend.services.jobs import Job, JobRunner
from backend.sim.disaster_response import (
    CAMERA,
    LIDAR,
    MEASURED_MOUNT,
    V_TARGET,
    disaster_response_truth,
    v_target_shots,
)
from backend.sim.marker_targets import (
    disaster_response_camera,
    field_views,
    render_test_field_image,
    simulated_test_field,
)
from backend.store.atomic import write_json_atomic
from backend.store.session import Session, SessionStore

DISASTER_RESPONSE_NAME = "disaster-response"
STAGING_DIR = ".disaster-response-building"
"""Folder under the sessions root where the session is built before it is moved into place (not a session)."""
BUILD_TITLE = "preparing the disaster-response session"
PIXEL_SIZE_UM = 4.8
"""The Blackfly's pixel pitch (um): the photogrammetric parameters are reported in mm too."""
DEVICE = "disaster-response simulator"


def ensure_disaster_response_session(store: SessionStore, *, fresh: bool = False,
                                     progress: ProgressCallback = no_progress) -> Session:
    """Open the disaster-response session, building it if missing (or ``fresh``: the old one is moved aside)."""
    return ensure_staged_session(store, DISASTER_RESPONSE_NAME, STAGING_DIR, lambda staging: _build(staging, progress),
                                 fresh=fresh)


def start_disaster_response_build(store: SessionStore, jobs: JobRunner, *, fresh: bool = False) -> Job:
    """:func:`ensure_disaster_response_session` as a job titled :data:`BUILD_TITLE` (its result: the session)."""
    return jobs.submit(BUILD_TITLE, lambda progress: ensure_disaster_response_session(store, fresh=fresh,
                                                                                      progress=progress))


def measured_rig() -> Rig:
    """The rig as a user first types it in: the camera at the root's origin, the Livox tape-measured on it."""
    rig = Rig("base_link")
    rig.add(Frame(CAMERA, "base_link", kind="camera", mount_sigma=None))
    rig.add(Frame(LIDAR, CAMERA, MEASURED_MOUNT, kind="lidar3d"))
    return rig


def _build(store: SessionStore, progress: ProgressCallback) -> Session:
    session = store.create(DISASTER_RESPONSE_NAME, rig=measured_rig(),
                           title="Simulated disaster-response robot: Blackfly + Livox, test field and V-targets")
    write_json_atomic(session.path / TRUTH_FILE, {"frames": {
        name: T.tolist() for name, T in disaster_response_truth().items()}})
    spec, _ = simulated_test_field(session.path)  # writes the survey where the session keeps it
    surveyed = TestField.parse(spec)
    session.set_board(f"testfield:{surveyed.dictionary}:{surveyed.marker_m:g}:{SESSION_SURVEY}")
    session.set_v_target(str(VTarget.parse(V_TARGET)))
    _add_test_field_views(session, surveyed, lambda f, m: progress(0.3 * f, m))
    result_id, _ = intrinsics_service.solve_session(
        session, CAMERA, IntrinsicsSettings(model="photogrammetric", pixel_size_um=PIXEL_SIZE_UM),
        progress=lambda f, m: progress(0.3 + 0.1 * f, m))
    # Standing in for a user who read the verdict: a 'check' (the image's outermost corners, which 40 markers in
    # 12 views do not reach) is taken and the confirmation recorded; a 'reject' is still refused.
    rig_service.accept(session, result_id, confirm=True)
    _add_v_target_pairs(session, lambda f, m: progress(0.4 + 0.6 * f, m))
    return session


def _add_test_field_views(session: Session, surveyed: TestField, progress: ProgressCallback) -> None:
    """The 12 test-field images of the camera (:func:`~backend.sim.marker_targets.field_views`), stored as lens
    views with the surveyed markers found in them."""
    camera = disaster_response_camera()
    views = field_views()
    for k, T_camera_wall in enumerate(views):
        progress(k / len(views), f"photographing the test field ({k + 1} of {len(views)})")
        image = render_test_field_image(camera, surveyed, T_camera_wall, np.random.default_rng(k))
        found = detect_test_field(image, surveyed, f"wall_{k:02d}.png")
        intrinsics_service.store_capture(session, CAMERA, image, found.detection, device=DEVICE, timestamp_s=float(k),
                                         source=Path(f"wall_{k:02d}.png").name)


def _add_v_target_pairs(session: Session, progress: ProgressCallback) -> None:
    """The V-target's 18 placements, each an image of the camera and a cloud of the Livox, stored as pairs."""
    progress(0.0, "placing the V-target in front of the robot")
    shots = v_target_shots(disaster_response_camera())
    for k, shot in enumerate(shots):
        progress((k + 1) / len(shots), f"storing V-target pairs ({k + 1} of {len(shots)})")
        stamp = 100.0 + k
        store_pair(session, CAMERA, LIDAR, Sample(stamp, image=shot.image),
                   Sample(stamp, points=shot.points_lidar, intensity=shot.intensity.astype(np.float32)),
                   device=DEVICE, detection=None, source=(f"{shot.name}.png", f"{shot.name}.npy"))
