"""A camera's exterior orientation in the session's wall test field."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Query, UploadFile

from backend.api.routes import deps
from backend.api.schemas import ExteriorRequest
from backend.api.uploads import UploadRoute, read_image_upload, upload_limit
from backend.calib.test_field import service
from backend.core.limits import MAX_IMAGE_UPLOAD_MB

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}", tags=["test field"], route_class=UploadRoute)


@router.post("/exterior", status_code=201)
def resect(sensor: str, body: ExteriorRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Pose the camera in the wall's frame from one capture (spatial resection on the surveyed markers it shows,
    through the camera's intrinsics) and keep the result: ``T_wall_camera`` (4x4, m) with its sigma, the
    photogrammetric X0/Y0/Z0 and omega/phi/kappa, the residuals and the verdict, as ``calib-studio exterior``
    prints each image's. One image's work, in the threadpool."""
    result_id, result = service.resect_capture(session, sensor, body.capture_id, body.intrinsics_result)
    return {"result_id": result_id, "capture_id": body.capture_id} | service.pose_entry(result)


@router.get("/exterior")
def list_exterior(sensor: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    """The camera's stored exterior orientations, oldest first."""
    return service.exterior_results(session, sensor)


@router.post("/exterior/images", status_code=201)
@upload_limit(MAX_IMAGE_UPLOAD_MB, "file")
def resect_upload(sensor: str, file: Annotated[UploadFile, File(description="an image of the wall")],
                  session: deps.SessionDep,
                  intrinsics_result: Annotated[str | None, Query(max_length=64, description="a stored intrinsics "
                                                                 "result to resect with; default: the rig's")] = None
                  ) -> dict[str, Any]:
    """Pose the camera from an uploaded image of the wall, which the session's board need not be in: the image is
    kept as the camera's capture (never a lens view) and the result beside it, as ``POST .../exterior`` does; an
    image that cannot be posed is refused naming it, and nothing is kept."""
    name, data = read_image_upload(file, "file")
    capture, result_id, result = service.resect_upload(session, sensor, name, data, intrinsics_result)
    return {"result_id": result_id, "capture_id": capture.id} | service.pose_entry(result)
