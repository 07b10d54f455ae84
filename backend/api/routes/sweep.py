"""The swept 2D scanner: calibrate its sweep geometry, accept it, look at a sweep as a LiDAR image; a board's corners
in its intensity image, the camera from them (the corners method) and a camera's pan axis."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Response

from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, JobStatus, SweepCalibrateRequest
from backend.api.sweep_corners_schemas import PanAxisSolveRequest, SweepCornersSolveRequest
from backend.calib.lidar_camera import sweep_corners_service as corners_service
from backend.calib.rig import service as rig
from backend.calib.sweep import service
from backend.calib.sweep.service import SweepCalibrationSettings
from backend.devices.image_io import encode_png

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}/sweep", tags=["sweep"])


@router.post("/calibrate", status_code=202, response_model=JobStatus)
def calibrate(sensor: str, body: SweepCalibrateRequest, session: deps.SessionDep,
              jobs: deps.JobsDep) -> dict[str, Any]:
    """Calibrate the sweep geometry in the background; poll ``/api/jobs/{id}`` for ``result_id``."""
    capture = service.swept_capture(session, sensor, body.capture_id)  # fail fast, before queueing
    settings = SweepCalibrationSettings(up_mount=body.up_mount, estimate_tilt=body.estimate_tilt)
    job = jobs.submit(f"sweep geometry of {sensor}", lambda progress: service.solve_session(
        session, sensor, capture.id, settings=settings, progress=progress))
    return job.status() | {"result_id": None}


@router.post("/accept")
def accept(sensor: str, body: AcceptRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Make a stored sweep geometry the sensor's (an older one reverts); the rig service applies it."""
    service.sweep_result(session, sensor, body.result_id)
    rig.accept(session, body.result_id, confirm=body.confirm)
    return session.info()


@router.get("/image/{capture_id}", responses={200: {"content": {"image/png": {}}}})
def image(sensor: str, capture_id: str, session: deps.SessionDep,
          mode: Annotated[service.ImageMode, Query(description="intensity or range (near = bright)")] = "intensity",
          result_id: Annotated[str | None, Query(description="re-assemble with this result's geometry")] = None
          ) -> Response:
    """The sweep as a PNG: one row per servo step, one column per beam."""
    return Response(encode_png(service.sweep_image(session, sensor, capture_id, result_id=result_id, mode=mode)),
                    media_type="image/png")


@router.get("/pairs")
def pairs(sensor: str, camera: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    """The stored image + sweep pairs of ``camera`` and the swept scanner, with the pan reading of each image."""
    return [{"name": pair.name, "image": pair.image.id, "cloud": pair.cloud.id, "board_found": pair.image.detection
             is not None, "pan_deg": corners_service.pan_reading_deg(pair.image)}
            for pair in corners_service.sweep_pairs(session, camera, sensor)]


@router.get("/corners/{capture_id}")
def corners(sensor: str, capture_id: str, session: deps.SessionDep) -> dict[str, Any]:
    """The session board's corners in a stored sweep's intensity image (one row per servo step, one column per beam)
    and in 3D (the scanner's mount frame, m); 422 naming the capture when the board is not found or too small."""
    found = corners_service.sweep_corners(session, sensor, capture_id)
    return {"capture": capture_id, "ids": found.ids.tolist(), "image_px": found.image_px.tolist(),
            "points_m": found.points_m.tolist(), "plane_rms_m": found.plane_rms_m,
            "image_size": [found.image.intensity.shape[1], found.image.intensity.shape[0]]}


@router.get("/corners/{capture_id}/image", responses={200: {"content": {"image/png": {}}}})
def corners_image(sensor: str, capture_id: str, session: deps.SessionDep) -> Response:
    """The intensity image around the board, rows stretched to the beams' angle, with the corners found marked."""
    return Response(encode_png(corners_service.sweep_corners_image(session, sensor, capture_id)[..., ::-1]),
                    media_type="image/png")


@router.post("/corners", status_code=202, response_model=JobStatus)
def solve_corners(sensor: str, body: SweepCornersSolveRequest, session: deps.SessionDep,
                  jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve ``T_camera_lidar`` by the corners method in the background; poll ``/api/jobs/{id}`` for ``result_id``
    (a ``lidar_camera`` result of method ``corners``, accepted like any)."""
    corners_service.corners_inputs(session, body.camera, sensor, body.pan_deg, body.image_ids)  # fail fast
    T_init = None if body.init is None else body.init.matrix()
    job = jobs.submit(f"{sensor} to {body.camera} (corners)", lambda progress: corners_service.solve_corners_session(
        session, body.camera, sensor, pan_deg=body.pan_deg, image_ids=body.image_ids, T_init=T_init,
        progress=progress)[0])
    return job.status() | {"result_id": None}


@router.post("/pan-axis", status_code=202, response_model=JobStatus)
def solve_pan_axis(sensor: str, body: PanAxisSolveRequest, session: deps.SessionDep,
                   jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve the camera's pose at pan reading 0 and its pan axis in the background; poll ``/api/jobs/{id}`` for
    ``result_id`` (a ``lidar_camera`` result of method ``pan_axis``, the axis in its diagnostics)."""
    corners_service.pan_inputs(session, body.camera, sensor)  # fail fast
    T_init = None if body.init is None else body.init.matrix()
    job = jobs.submit(f"pan axis of {body.camera} on {sensor}", lambda progress: corners_service.solve_pan_session(
        session, body.camera, sensor, T_init=T_init, progress=progress)[0])
    return job.status() | {"result_id": None}
