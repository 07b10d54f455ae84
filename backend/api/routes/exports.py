"""Downloads of accepted calibrations."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import PlainTextResponse

from backend.api.routes import deps
from backend.services.exports import EXPORT_FORMATS, MEDIA_TYPES, Convention, ExportFormat, export_text

router = APIRouter(tags=["exports"])


@router.get("/exports/formats")
def formats() -> dict[str, str]:
    return EXPORT_FORMATS


@router.get("/sessions/{name}/results")
def list_results(session: deps.SessionDep, sensor: str | None = None,
                 kind: str | None = None) -> list[dict[str, Any]]:
    """Every stored result (oldest first), summarised; fetch one for its full record."""
    keep = ("id", "sensor", "kind", "created", "rms_px", "camera", "std", "seconds")
    return [{k: r.get(k) for k in keep} for r in session.results(sensor, kind)]


@router.get("/sessions/{name}/results/{result_id}")
def get_result(result_id: str, session: deps.SessionDep) -> dict[str, Any]:
    return session.result(result_id)


@router.get("/sessions/{name}/export/{fmt}", response_class=PlainTextResponse,
            responses={200: {"content": {"application/yaml": {}, "application/xml": {}, "text/x-python": {}}}})
def export(fmt: ExportFormat, session: deps.SessionDep,
           sensor: Annotated[str | None, Query(description="camera for the one-camera formats")] = None,
           convention: Annotated[Convention | None, Query(
               description="rig / urdf / launch: 'optical' (default: cameras as their optical frames) or 'body' "
                           "(each camera a body frame with a CAM_optical_frame child)")] = None,
           cameras: Annotated[list[str] | None, Query(
               description="kalibr: the cameras to write, in order (repeat, or comma-separated); default every "
                           "camera Kalibr can describe")] = None,
           ) -> PlainTextResponse:
    subset = None if cameras is None else [name for value in cameras for name in value.split(",") if name]
    filename, text = export_text(session, fmt, sensor, convention=convention, cameras=subset)
    return PlainTextResponse(text, media_type=MEDIA_TYPES.get(fmt, "application/yaml"),
                             headers={"Content-Disposition": f'attachment; filename="{filename}"'})
