"""Multi-camera rigs: synchronised sets (captured or imported from a bag), joint solves, the stereo check of a pair
and acceptance (through the one rig service)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Response

from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, JobStatus, MulticamBagImport, MulticamSetCapture, MulticamSolveRequest
from backend.calib._session import result_of
from backend.calib.multicam import capture as capture_service
from backend.calib.multicam import service
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.devices.image_io import encode_png

router = APIRouter(prefix="/sessions/{name}/multicam", tags=["multicam"])


def _set_dict(found: capture_service.MulticamSet) -> dict[str, Any]:
    return {"name": found.name, "cameras": found.cameras, "board_found": found.cameras_with_board,
            "captures": {camera: record.id for camera, record in found.captures.items()}}


@router.get("/sets")
def list_sets(session: deps.SessionDep, cameras: str | None = None) -> list[dict[str, Any]]:
    """The session's synchronised sets (with ``cameras=a,b``: those holding at least two of them)."""
    names = None if cameras is None else [c for c in cameras.split(",") if c]
    return [_set_dict(s) for s in capture_service.stored_sets(session, names)]


@router.post("/capture", status_code=202, response_model=JobStatus)
def capture(body: MulticamSetCapture, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Read every camera at once and keep the set; the job's ``summary`` is the set."""
    service.check_cameras(body.cameras)
    capture_service.check_capture_devices(session, body.cameras)  # fail fast, before queueing
    job = jobs.submit(f"set of {', '.join(body.cameras)}", lambda progress: _set_dict(
        capture_service.capture_set_from_devices(session, body.cameras, tolerance_s=body.tolerance_s,
                                                 require_board=body.require_board, progress=progress)))
    return job.status() | {"result_id": None, "summary": None}


@router.post("/import", status_code=202, response_model=JobStatus)
def import_bag(body: MulticamBagImport, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Import synchronised sets from a bag's image topics; the job's ``summary`` is the import report."""
    service.check_cameras(list(body.topics))
    job = jobs.submit(f"sets from {body.path}", lambda progress: capture_service.import_bag_sets(
        session, body.path, body.topics, tolerance_s=body.tolerance_s, every=body.every, limit=body.limit,
        start_s=body.start_s, end_s=body.end_s, progress=progress).to_dict())
    return job.status() | {"result_id": None, "summary": None}


@router.post("/solve", status_code=202, response_model=JobStatus)
def solve(body: MulticamSolveRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve the rig of ``cameras`` jointly in the background; poll ``/api/jobs/{id}`` for ``result_id``."""
    service.check_cameras(body.cameras)
    service.session_observations(session, body.cameras, body.set_names)  # fail fast, before queueing
    job = jobs.submit(f"rig of {', '.join(body.cameras)}", lambda progress: service.solve_session(
        session, body.cameras, refine_intrinsics=body.refine_intrinsics, set_names=body.set_names,
        progress=progress)[0])
    return job.status() | {"result_id": None}


@router.post("/accept")
def accept(body: AcceptRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Accept a multicam result: each camera becomes an edge from the reference in the rig graph, refined lenses
    become the cameras' (an older result reverts); the answer is the session with the rig update."""
    result_of(session, service.KIND, body.result_id)
    update = rig_service.accept(session, body.result_id, confirm=body.confirm, revert=body.revert)
    return session.info() | {"rig_update": update.to_dict()}


Camera = Annotated[str, Query(description="a camera of the result")]
SetName = Annotated[str, Query(alias="set", description="a set of the result in which both cameras saw the board")]


@router.get("/results/{result_id}/stereo")
def stereo(result_id: str, left: Camera, right: Camera, set_name: SetName, session: deps.SessionDep
           ) -> dict[str, Any]:
    """The stereo check of two cameras of a result on one set: epipolar error (px), rectified row offset (px),
    baseline (m)."""
    return service.stereo_check(session, result_id, left, right, set_name).to_dict()


@router.get("/results/{result_id}/stereo.png", responses={200: {"content": {"image/png": {}}}})
def stereo_preview(result_id: str, left: Camera, right: Camera, set_name: SetName, session: deps.SessionDep
                   ) -> Response:
    """The pair's rectified images side by side (stacked for a vertical pair) with lines that corners should
    share; a 422 says why when the pair cannot be rectified together."""
    check = service.stereo_check(session, result_id, left, right, set_name)
    if check.preview_bgr is None:
        raise InputError(f"no rectified preview of {left} and {right}: {check.no_preview}", right)
    return Response(encode_png(check.preview_bgr), media_type="image/png")
