"""A camera's exterior orientation in a wall test field's frame, for the API, the studio and the CLI.

image (a session's capture, or a file) -> the surveyed markers in it, through the camera's lens -> spatial
resection (:func:`~backend.calib.test_field.exterior.resect`) -> a result kept in the session's history (kind
``test_field``: ``T_wall_camera``, never accepted into the rig, whose frames do not hold the wall).

The test field is the session's (:func:`~backend.calib._session.session_test_field`: beside the board, or the board
itself), and the markers are searched for afresh in the stored image, so any capture of the camera that shows the
wall serves: a lens view, or the image of a LiDAR-camera pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib._session import check_camera, session_test_field
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
from backend.calib.test_field.detection import detect_test_field
from backend.calib.test_field.exterior import resect
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.test_field import TestField
from backend.devices.image_io import decode_image_bytes
from backend.store.schema import CaptureRecord
from backend.store.session import Session

KIND = "test_field"
"""The kind of an exterior-orientation result (:func:`~backend.calib.test_field.exterior.resect`)."""


def resect_image(image: np.ndarray, camera: CameraIntrinsics, test_field: TestField, name: str,
                 lens: LensUncertainty | None = None) -> TransformResult:
    """``T_wall_camera`` of one image called ``name``: its surveyed markers found through ``camera``'s lens, then
    resected (``lens``: the intrinsics' own sigma, carried into the pose's); markers left out are in the result's
    warnings. Raises :class:`InputError` naming ``name`` when too few surveyed markers are seen."""
    found = detect_test_field(image, test_field, name, camera)
    if found.detection is None:
        raise InputError(found.reason, name)
    result = resect(camera, test_field, found.detection, name, lens)
    result.warnings[:0] = found.notes
    return result


def pose_entry(result: TransformResult) -> dict[str, Any]:
    """One image's pose as the CLI prints it and the API returns it (``T_wall_camera``, 4x4, m)."""
    return {"T_wall_camera": result.T_parent_child.tolist(), "std": result.std, "residuals": result.residuals,
            "exterior_orientation": result.diagnostics["exterior_orientation"], "verdict": result.verdict.to_dict(),
            "warnings": result.warnings}


@dataclass
class SessionLens:
    """The lens a resection in a session uses: the intrinsics, their sigma when a result holds it, and where they
    come from (a result's id, or the rig's)."""

    camera: CameraIntrinsics
    uncertainty: LensUncertainty | None
    source: str


def session_camera(session: Session, camera: str, intrinsics_result: str | None = None) -> SessionLens:
    """The lens a resection uses: the stored intrinsics result ``intrinsics_result`` if given, else the camera's
    intrinsics in the rig (the accepted result's, with its sigma)."""
    check_camera(session, camera)
    if intrinsics_result is None:
        intrinsics_result = session.accepted(f"{camera}/intrinsics")
        if intrinsics_result is None:
            intrinsics = session.rig.get(camera).intrinsics
            if intrinsics is None:
                raise InputError(f"{camera} has no intrinsics yet: solve and accept them in step 3 (a board's or the "
                                 "test field's views), or name a stored intrinsics result", "intrinsics_result")
            return SessionLens(intrinsics, None, "the rig's intrinsics")
    record = intrinsics_service.intrinsics_result(session, camera, intrinsics_result)
    return SessionLens(CameraIntrinsics.from_dict(record["camera"]), LensUncertainty.from_record(record),
                       intrinsics_result)


def resect_capture(session: Session, camera: str, capture_id: str, intrinsics_result: str | None = None
                   ) -> tuple[str, TransformResult]:
    """Pose ``camera`` in the session's test field from its capture ``capture_id`` and keep the result (not
    accepted: the rig holds no wall). Returns the result's id and the result, its child the camera."""
    lens = session_camera(session, camera, intrinsics_result)
    test_field = session_test_field(session)
    capture = next((c for c in session.captures(camera) if c.id == capture_id), None)
    if capture is None:
        raise InputError(f"{camera} has no capture {capture_id!r}", "capture_id", status_code=404)
    image = session.capture_image(camera, capture_id)
    result = _resected(image, camera, capture.source or capture_id, lens, test_field)
    return _kept(session, camera, capture_id, result), result


def resect_upload(session: Session, camera: str, name: str, data: bytes, intrinsics_result: str | None = None
                  ) -> tuple[CaptureRecord, str, TransformResult]:
    """Pose ``camera`` from an uploaded image of the wall called ``name`` (one the session's board need not be in):
    the image is kept as the camera's capture (marked ``wall_view``, never a lens view) and the result
    beside it; an image that cannot be posed is refused and nothing is kept."""
    lens = session_camera(session, camera, intrinsics_result)
    test_field = session_test_field(session)
    image = decode_image_bytes(data, name)
    result = _resected(image, camera, name, lens, test_field)
    with session.lock:
        capture = intrinsics_service.store_capture(session, camera, image, None, device="upload", timestamp_s=0.0,
                                                   source=Path(name).name,
                                                   meta={intrinsics_service.WALL_VIEW_META: True})
        return capture, _kept(session, camera, capture.id, result), result


def _resected(image: np.ndarray, camera: str, name: str, lens: SessionLens, test_field: TestField) -> TransformResult:
    """:func:`resect_image` of a session camera's image, its child the camera and its settings saying what it used."""
    width, height = lens.camera.width, lens.camera.height
    if (image.shape[1], image.shape[0]) != (width, height):
        raise InputError(f"{name} is {image.shape[1]}x{image.shape[0]} px but {camera}'s intrinsics ({lens.source}) "
                         f"are for {width}x{height} px", name)
    result = resect_image(image, lens.camera, test_field, name, lens.uncertainty)
    result.child = camera
    result.settings = {"test_field": str(test_field), "intrinsics": lens.source, "image": name}
    return result


def _kept(session: Session, camera: str, capture_id: str, result: TransformResult) -> str:
    """Keep ``result`` of the capture ``capture_id`` in the session's history; returns its id."""
    result.settings["capture_id"] = capture_id
    return session.add_result(camera, result.to_record(), inputs=[capture_id])


def shows_the_wall(capture: CaptureRecord) -> bool:
    """Whether a capture is known to show a test field: kept for its pose, or a lens view of a test field."""
    return bool(capture.meta.get(intrinsics_service.WALL_VIEW_META)) or (
        capture.detection is not None and (capture.board or "").startswith("testfield:"))


def exterior_results(session: Session, camera: str) -> list[dict[str, Any]]:
    """The camera's stored exterior orientations, oldest first."""
    check_camera(session, camera)
    return session.results(camera, KIND)
