"""Camera captures and the intrinsics solve."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Query, Response, UploadFile

from backend.api.client_watch import ClientProgressDep
from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, ImportResponse, IntrinsicsSolveRequest, JobStatus
from backend.api.uploads import UploadRoute, read_image_upload, upload_limit
from backend.calib.intrinsics import service
from backend.calib.intrinsics.service import IntrinsicsSettings
from backend.calib.rig import service as rig
from backend.core.limits import MAX_IMAGE_UPLOAD_MB
from backend.devices.image_io import encode_jpeg

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}", tags=["intrinsics"], route_class=UploadRoute)


@router.get("/captures")
def list_captures(sensor: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    return [c.model_dump(exclude={"detection"}) | {"board_found": c.detection is not None}
            for c in session.captures(sensor)]


@router.post("/captures", status_code=201, response_model=ImportResponse)
@upload_limit(MAX_IMAGE_UPLOAD_MB, "files")
def upload_captures(
    sensor: str,
    files: Annotated[list[UploadFile], File()],
    session: deps.SessionDep,
    progress: ClientProgressDep,
    skip_unusable: Annotated[bool, Query(description="store the images with a board and report the others, "
                                                     "instead of rejecting the batch")] = False,
) -> dict[str, Any]:
    """Add images of the board (all or nothing, unless ``skip_unusable``). Only the base name of an upload is
    kept; files are stored under new ids. Runs in the threadpool: decoding and detection never hold up the
    server's other requests; a client that leaves stops it at the next image, and nothing is stored."""
    payload = [read_image_upload(f, "files") for f in files]
    report = service.import_images(session, sensor, payload, skip_unusable=skip_unusable, progress=progress)
    return {"added": [c.model_dump(exclude={"detection"}) for c in report.added], "skipped": report.skipped,
            "notes": report.notes}


@router.get("/captures/{capture_id}/image", responses={200: {"content": {"image/jpeg": {}}}})
def capture_image(sensor: str, capture_id: str, session: deps.SessionDep) -> Response:
    return Response(encode_jpeg(session.capture_image(sensor, capture_id)), media_type="image/jpeg")


@router.post("/intrinsics/solve", status_code=202, response_model=JobStatus)
def solve(sensor: str, body: IntrinsicsSolveRequest, session: deps.SessionDep,
          jobs: deps.JobsDep) -> dict[str, Any]:
    """Start a solve in the background; poll ``/api/jobs/{id}``, whose ``result_id`` names the stored result."""
    settings = IntrinsicsSettings(**body.model_dump(exclude={"capture_ids"}))
    service.session_views(session, sensor, body.capture_ids)  # fail fast, before queueing
    job = jobs.submit(f"intrinsics of {sensor}",
                      lambda progress: service.solve_session(session, sensor, settings, body.capture_ids, progress)[0])
    return job.status() | {"result_id": None}


@router.post("/intrinsics/accept")
def accept(sensor: str, body: AcceptRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Make a stored result the camera's intrinsics (an older one reverts); the rig service applies it."""
    service.intrinsics_result(session, sensor, body.result_id)
    rig.accept(session, body.result_id, confirm=body.confirm)
    return session.info()
