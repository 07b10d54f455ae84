"""LiDAR clouds and the LiDAR-to-LiDAR solve."""

from __future__ import annotations

from dataclasses import replace
from typing import Annotated, Any

from fastapi import APIRouter, File, UploadFile

from backend.api.client_watch import ClientProgressDep
from backend.api.routes import deps
from backend.api.schemas import JobStatus, LidarLidarAccept, LidarLidarSolveRequest
from backend.api.uploads import UploadRoute, save_uploads, upload_folder, upload_limit
from backend.calib.lidar_lidar import service
from backend.calib.lidar_lidar.service import LidarLidarSettings
from backend.calib.rig import service as rig_service
from backend.core.limits import MAX_CLOUD_UPLOAD_MB

router = APIRouter(prefix="/sessions/{name}", tags=["lidar"], route_class=UploadRoute)


@router.post("/sensors/{sensor}/clouds", status_code=201)
@upload_limit(MAX_CLOUD_UPLOAD_MB, "files")
def upload_clouds(sensor: str, files: Annotated[list[UploadFile], File()],
                  session: deps.SessionDep, progress: ClientProgressDep) -> dict[str, Any]:
    """Add cloud files (.pcd, .ply, .las, .laz, .npy, .lvx); an unreadable file rejects the batch, naming it, and
    nothing of it is stored. The files are copied in chunks to the session's folder and read from there, in
    the threadpool; a client that leaves stops it at the next file, and nothing is stored."""
    with upload_folder(session) as folder:
        added = service.import_clouds(session, sensor, save_uploads(files, "files", folder), progress)
    return {"added": [c.model_dump() for c in added]}


@router.get("/lidar-lidar/pairs")
def pairs(source: str, target: str, session: deps.SessionDep) -> list[tuple[str, str]]:
    """The default frame pairs of ``source`` and ``target``, to pick scenes from: captures paired by time stamp
    (within 1 s, never by number; uploads in upload order); 422 when none pair, naming the captures."""
    return service.pair_ids(session, source, target)


@router.get("/lidar-lidar/pairing")
def pairing(source: str, target: str, session: deps.SessionDep) -> dict[str, Any]:
    """``{"pairs": [[source id, target id], ...], "unpaired": [why, ...]}``: the pairs, and each capture that
    found no partner, named."""
    found = service.pairing(session, source, target)
    return {"pairs": found.pairs, "unpaired": found.unpaired}


@router.post("/lidar-lidar/solve", status_code=202, response_model=JobStatus)
def solve(body: LidarLidarSolveRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Register ``source`` into ``target`` over the chosen frame pairs (scenes) in the background; poll
    ``/api/jobs/{id}`` for ``result_id``."""
    service.capture_pairs(session, body.source, body.target, body.pairs)  # fail fast, before queueing
    T_init = None if body.init is None else body.init.matrix()
    settings = LidarLidarSettings()
    if body.voxel_m is not None:
        settings = replace(settings, voxel_m=body.voxel_m)
    job = jobs.submit(f"{body.source} to {body.target}", lambda progress: service.solve_session(
        session, body.source, body.target, T_init=T_init, use_rig_guess=body.use_rig_guess, settings=settings,
        pairs=body.pairs, progress=progress)[0])
    return job.status() | {"result_id": None}


@router.post("/sensors/{sensor}/lidar-lidar/accept")
def accept(sensor: str, body: LidarLidarAccept, session: deps.SessionDep) -> dict[str, Any]:
    """Make a LiDAR-to-LiDAR result of ``sensor`` (the source LiDAR) an edge of the rig and re-solve the rig
    (a ``check`` verdict needs ``confirm``; accepting an older result reverts to it)."""
    service.check_result(session, sensor, body.result_id)
    rig_service.accept(session, body.result_id, confirm=body.confirm)
    return session.info()
