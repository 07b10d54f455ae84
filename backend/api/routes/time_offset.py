"""Time offsets between two sensors from their captures of one moving board: measured in the background, kept, and
accepted as the second sensor's clock offset in the rig."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response
from pydantic import BaseModel, Field

from backend.api.routes import deps
from backend.api.schemas import JobStatus
from backend.calib._session import result_of
from backend.calib.time_offset import service
from backend.plots.render import to_svg
from backend.plots.time_offset import aligned_signals

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}/time-offset", tags=["time-offset"])


class TimeOffsetRequest(BaseModel):
    reference: str = Field(max_length=64, description="sensor a, whose clock the offset is measured from (the camera)")
    max_offset_s: float = Field(0.5, gt=0, le=5.0, description="the offset is searched within ±this (s)")
    recording: str | None = Field(None, max_length=64, description="measure from this recording's captures alone "
                                  "(POST /api/sessions/{name}/recordings); default: every capture of both sensors")


@router.post("", status_code=202, response_model=JobStatus)
def solve(sensor: str, body: TimeOffsetRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Measure ``t_sensor = t_reference + offset`` from both sensors' captures (of one ``recording``, or all) in the
    background (a camera and a 3D LiDAR, or two cameras, that watched a board carried through both views). Poll
    ``/api/jobs/{id}`` for ``result_id``; accepting it (``POST /api/sessions/{name}/accept``) sets the sensor's
    clock offset."""
    settings = service.settings(body.max_offset_s)
    service.check_pair(session, body.reference, sensor, body.recording)  # fail fast, before queueing
    job = jobs.submit(f"time offset of {sensor} from {body.reference}", lambda progress: service.solve_session(
        session, body.reference, sensor, settings, recording=body.recording, progress=progress))
    return job.status() | {"result_id": None}


@router.get("")
def results(sensor: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    """The sensor's time-offset results, oldest first, with their ids."""
    return service.time_offset_results(session, sensor)


@router.get("/{result_id}/plot.svg", response_class=Response)
def plot(sensor: str, result_id: str, session: deps.SessionDep) -> Response:
    """The result's plot (SVG): both signals on the reference's clock and axes, and the score over the offsets."""
    record = result_of(session, service.KIND, result_id, sensor)
    return Response(to_svg(aligned_signals(record)), media_type="image/svg+xml")
