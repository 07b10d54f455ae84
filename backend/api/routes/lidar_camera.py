"""LiDAR-to-camera pairs, solves, transforms set by hand, acceptance and overlays."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, File, Form, Query, Response, UploadFile
from fastapi.responses import FileResponse

from backend.api.routes import deps
from backend.api.schemas import (
    AcceptRequest,
    JobStatus,
    LidarCameraManual,
    LidarCameraPairCapture,
    LidarCameraSolveRequest,
)
from backend.core.overlay import OverlayStyle, render_overlay
from backend.core.transforms import from_xyz_ypr
from backend.devices.image_io import encode_jpeg
from backend.services import lidar_camera as service
from backend.services import lidar_camera_pairs as pairs_service

router = APIRouter(prefix="/sessions/{name}", tags=["lidar-camera"])


def _pair_dict(pair: pairs_service.CapturePair) -> dict[str, Any]:
    return {"name": pair.name, "camera": pair.camera, "image": pair.image.id, "lidar": pair.lidar,
            "cloud": pair.cloud.id, "board_found": pair.image.detection is not None,
            "n_points": pair.cloud.n_points, "timestamp_s": pair.image.timestamp_s}


@router.get("/lidar-camera/pairs")
def list_pairs(camera: str, lidar: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    return [_pair_dict(p) for p in pairs_service.stored_pairs(session, camera, lidar)]


@router.post("/lidar-camera/pairs", status_code=201)
async def upload_pair(camera: Annotated[str, Form()], lidar: Annotated[str, Form()],
                      image: Annotated[UploadFile, File()], cloud: Annotated[UploadFile, File()],
                      session: deps.SessionDep) -> dict[str, Any]:
    """Add an image and a cloud of the same moment; an unreadable file or a wrong image size stores nothing."""
    pair = pairs_service.import_pair(session, camera, lidar, (image.filename or "image", await image.read()),
                                     (cloud.filename or "cloud", await cloud.read()))
    return _pair_dict(pair)


@router.post("/lidar-camera/capture", status_code=202, response_model=JobStatus)
def capture(body: LidarCameraPairCapture, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Capture a pair from both devices once the board holds still; the job's ``summary`` is the pair."""
    pairs_service.check_camera(session, body.camera)  # fail fast, before queueing
    job = jobs.submit(f"pair {body.camera}+{body.lidar}", lambda progress: _pair_dict(
        pairs_service.capture_pair_from_devices(session, body.camera, body.lidar, require_board=body.require_board,
                                                progress=progress)))
    return job.status() | {"result_id": None, "summary": None}


@router.post("/lidar-camera/solve", status_code=202, response_model=JobStatus)
def solve(body: LidarCameraSolveRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve ``T_camera_lidar`` from the stored pairs in the background; poll ``/api/jobs/{id}`` for ``result_id``."""
    service.load_pairs(session, body.camera, body.lidar, body.image_ids)  # fail fast, before queueing
    T_init = None
    if body.init_xyz_m is not None or body.init_ypr_deg is not None:
        T_init = from_xyz_ypr(np.array(body.init_xyz_m or (0, 0, 0)), np.radians(body.init_ypr_deg or (0, 0, 0)))
    job = jobs.submit(f"{body.lidar} to {body.camera} ({body.method})", lambda progress: service.solve_session(
        session, body.camera, body.lidar, method=body.method, T_init=T_init, image_ids=body.image_ids,
        plate_margin_m=body.plate_margin_m, translation_prior_m=body.translation_prior_m, progress=progress)[0])
    return job.status() | {"result_id": None}


@router.post("/lidar-camera/manual", status_code=201)
def manual(body: LidarCameraManual, session: deps.SessionDep) -> dict[str, Any]:
    """Keep a hand-set ``T_camera_lidar`` as a result (not yet accepted)."""
    T_camera_lidar = from_xyz_ypr(np.array(body.xyz_m), np.radians(body.ypr_deg))
    return {"result_id": service.store_manual(session, body.camera, body.lidar, T_camera_lidar, inputs=body.inputs)}


@router.post("/sensors/{sensor}/lidar-camera/accept")
def accept(sensor: str, body: AcceptRequest, session: deps.SessionDep) -> dict[str, Any]:
    service.accept(session, sensor, body.result_id, body.confirm)
    return session.info()


@router.get("/lidar-camera/overlay/{image_id}", responses={200: {"content": {"image/jpeg": {}}}})
def overlay(image_id: str, camera: str, lidar: str, session: deps.SessionDep,
            result_id: Annotated[str | None, Query(description="draw with this result's T_camera_lidar; "
                                                              "default the rig's")] = None) -> Response:
    """One stored pair's image with its cloud drawn on it (depth colours)."""
    loaded = service.load_pairs(session, camera, lidar, [image_id])[0]
    intrinsics = service.camera_intrinsics(session, camera)
    T_camera_lidar = (session.rig.T_a_b(camera, lidar) if result_id is None
                      else service.result_transform(session, lidar, result_id))
    drawn, _ = render_overlay(loaded.image, loaded.points, loaded.intensity, T_camera_lidar, intrinsics,
                              OverlayStyle())
    return Response(encode_jpeg(drawn), media_type="image/jpeg")


@router.get("/results/{result_id}/files/{file_name}")
def result_file(result_id: str, file_name: str, session: deps.SessionDep) -> FileResponse:
    """A file stored with a result, e.g. ``overlay_before.jpg`` and ``overlay_after.jpg`` of a LiDAR-camera solve."""
    return FileResponse(session.result_file(result_id, file_name))
