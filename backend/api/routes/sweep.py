"""The swept 2D scanner: calibrate its sweep geometry, accept it, look at a sweep as a LiDAR image."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Response

from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, JobStatus, SweepCalibrateRequest
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
