"""Multi-camera rigs: synchronised sets (captured or imported from a bag), joint solves and acceptance."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.routes import deps
from backend.api.schemas import AcceptRequest, JobStatus, MulticamBagImport, MulticamSetCapture, MulticamSolveRequest
from backend.services import multicam as service
from backend.services import multicam_capture as capture_service

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
    """Mount the result's cameras relative to its reference (an older result reverts)."""
    service.accept(session, body.result_id, body.confirm)
    return session.info()
