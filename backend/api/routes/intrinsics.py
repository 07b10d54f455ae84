"""Camera captures and the intrinsics solve."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, File, Query, Response, UploadFile

from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, ImportResponse, IntrinsicsSolveRequest, JobStatus
from backend.devices.image_io import encode_jpeg
from backend.services import intrinsics as service
from backend.services.jobs import JobRunner
from backend.solvers.intrinsics import IntrinsicsSettings
from backend.store.session import Session

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}", tags=["intrinsics"])


@router.get("/captures")
def list_captures(sensor: str, session: Session = Depends(deps.session)) -> list[dict[str, Any]]:
    return [c.model_dump(exclude={"detection"}) | {"board_found": c.detection is not None}
            for c in session.captures(sensor)]


@router.post("/captures", status_code=201, response_model=ImportResponse)
async def upload_captures(sensor: str, files: list[UploadFile] = File(...),
                          skip_unusable: bool = Query(False, description="store the images with a board and report "
                                                                         "the others, instead of rejecting the batch"),
                          session: Session = Depends(deps.session)) -> dict[str, Any]:
    """Add images of the board. Only the base name of an upload is kept; files are stored under new ids."""
    payload = [(f.filename or "upload", await f.read()) for f in files]
    report = service.import_images(session, sensor, payload, skip_unusable=skip_unusable)
    return {"added": [c.model_dump(exclude={"detection"}) for c in report.added], "skipped": report.skipped}


@router.get("/captures/{capture_id}/image", responses={200: {"content": {"image/jpeg": {}}}})
def capture_image(sensor: str, capture_id: str, session: Session = Depends(deps.session)) -> Response:
    return Response(encode_jpeg(session.capture_image(sensor, capture_id)), media_type="image/jpeg")


@router.post("/intrinsics/solve", status_code=202, response_model=JobStatus)
def solve(sensor: str, body: IntrinsicsSolveRequest, session: Session = Depends(deps.session),
          jobs: JobRunner = Depends(deps.jobs)) -> dict[str, Any]:
    """Start a solve in the background; poll ``/api/jobs/{id}``, whose ``result_id`` names the stored result."""
    settings = IntrinsicsSettings(**body.model_dump(exclude={"capture_ids"}))
    session.rig.get(sensor)
    job = jobs.submit(f"intrinsics of {sensor}",
                      lambda progress: service.solve_session(session, sensor, settings, body.capture_ids, progress)[0])
    return job.status() | {"result_id": None}


@router.post("/intrinsics/accept")
def accept(sensor: str, body: AcceptRequest, session: Session = Depends(deps.session)) -> dict[str, Any]:
    service.accept(session, sensor, body.result_id)
    return session.info()
