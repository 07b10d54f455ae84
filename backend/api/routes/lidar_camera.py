"""LiDAR-to-camera pairs, solves, transforms set by hand, acceptance, overlays and the full-size overlay page."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, File, Form, Query, Response, UploadFile
from fastapi.responses import FileResponse, HTMLResponse

from backend.api.routes import deps
from backend.api.schemas import (
    AcceptRequest,
    JobStatus,
    LidarCameraManual,
    LidarCameraPairCapture,
    LidarCameraSolveRequest,
)
from backend.api.uploads import UploadRoute, file_name, read_image_upload, save_upload, upload_folder, upload_limit
from backend.calib._session import check_camera, check_lidar
from backend.calib.lidar_camera import capture as pairs_service
from backend.calib.lidar_camera import service
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.core.limits import MAX_CLOUD_UPLOAD_MB, MAX_IMAGE_PIXELS
from backend.core.overlay import COLOUR_MODES, OverlayStyle, with_legend
from backend.core.transforms import from_xyz_ypr
from backend.devices.image_io import encode_jpeg

router = APIRouter(prefix="/sessions/{name}", tags=["lidar-camera"], route_class=UploadRoute)

VIEW_PAGE = Path(__file__).resolve().parents[3] / "frontend_assets" / "overlay_view.html"
"""The full-size overlay page: zoom and pan over one pair's or every pair's overlay at the image's resolution."""


def _pair_dict(pair: pairs_service.CapturePair) -> dict[str, Any]:
    return {"name": pair.name, "camera": pair.camera, "image": pair.image.id, "lidar": pair.lidar,
            "cloud": pair.cloud.id, "board_found": pair.image.detection is not None,
            "n_points": pair.cloud.n_points, "timestamp_s": pair.image.timestamp_s,
            "clock_offsets_s": pair.clock_offsets_s}


@router.get("/lidar-camera/pairs")
def list_pairs(camera: str, lidar: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    return [_pair_dict(p) for p in pairs_service.stored_pairs(session, camera, lidar)]


@router.post("/lidar-camera/pairs", status_code=201)
@upload_limit(MAX_CLOUD_UPLOAD_MB, "cloud")
def upload_pair(camera: Annotated[str, Form()], lidar: Annotated[str, Form()],
                image: Annotated[UploadFile, File()], cloud: Annotated[UploadFile, File()],
                session: deps.SessionDep) -> dict[str, Any]:
    """Add an image and a cloud of the same moment; an unreadable file or a wrong image size stores nothing.
    The cloud is copied in chunks to the session's folder and read from there, in the threadpool."""
    image_file = read_image_upload(image, "image", "image")
    cloud_name = file_name(cloud, "cloud", "cloud")
    with upload_folder(session) as folder:
        pair = pairs_service.import_pair(session, camera, lidar, image_file,
                                         (cloud_name, save_upload(cloud, cloud_name, folder)))
    return _pair_dict(pair)


@router.post("/lidar-camera/capture", status_code=202, response_model=JobStatus)
def capture(body: LidarCameraPairCapture, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Capture a pair from both devices once the board holds still; the job's ``summary`` is the pair."""
    check_camera(session, body.camera)  # fail fast, before queueing
    check_lidar(session, body.lidar)
    job = jobs.submit(f"pair {body.camera}+{body.lidar}", lambda progress: _pair_dict(
        pairs_service.capture_pair_from_devices(session, body.camera, body.lidar, require_board=body.require_board,
                                                integration_s=body.integration_s, progress=progress)))
    return job.status() | {"result_id": None, "summary": None}


@router.post("/lidar-camera/solve", status_code=202, response_model=JobStatus)
def solve(body: LidarCameraSolveRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve ``T_camera_lidar`` from the stored pairs in the background; poll ``/api/jobs/{id}`` for ``result_id``."""
    service.check_method(body.method, "method", body.cross_check)  # fail fast, before queueing
    service.load_pairs(session, body.camera, body.lidar, body.image_ids)
    T_init = None if body.init is None else body.init.matrix()
    job = jobs.submit(f"{body.lidar} to {body.camera} ({body.method})", lambda progress: service.solve_session(
        session, body.camera, body.lidar, method=body.method, T_init=T_init, image_ids=body.image_ids,
        plate_margin_m=body.plate_margin_m, translation_prior_m=body.translation_prior_m,
        cross_check=body.cross_check, progress=progress)[0])
    return job.status() | {"result_id": None}


@router.post("/lidar-camera/manual", status_code=201)
def manual(body: LidarCameraManual, session: deps.SessionDep) -> dict[str, Any]:
    """Keep a hand-set ``T_camera_lidar`` as a result (not yet accepted)."""
    T_camera_lidar = body.pose.matrix()
    return {"result_id": service.store_manual(session, body.camera, body.lidar, T_camera_lidar, inputs=body.inputs)}


@router.post("/sensors/{sensor}/lidar-camera/accept")
def accept(sensor: str, body: AcceptRequest, session: deps.SessionDep) -> dict[str, Any]:
    """Accept a LiDAR-to-camera result of ``sensor`` into the rig (:func:`backend.calib.rig.service.accept`)."""
    service.lidar_camera_record(session, sensor, body.result_id)
    rig_service.accept(session, body.result_id, confirm=body.confirm)
    return session.info()


def _numbers(text: str, count: int, field: str, unit: str) -> np.ndarray:
    """``count`` comma-separated finite numbers from the query field ``field``; InputError naming it otherwise."""
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        values = np.zeros(0)
    if len(values) != count or not np.isfinite(values).all():
        raise InputError(f"expected {count} comma-separated numbers ({unit}), got {text!r}", field)
    return values


def _overlay_transform(session, camera: str, lidar: str, result_id: str | None, xyz_m: str | None,
                       ypr_deg: str | None) -> np.ndarray:
    """``T_camera_lidar`` to draw with: given as xyz + ypr, a result's, or the rig's."""
    if (xyz_m is None) != (ypr_deg is None):
        raise InputError("give both xyz_m and ypr_deg, or neither", "xyz_m" if xyz_m is None else "ypr_deg")
    if xyz_m is not None:
        if result_id is not None:
            raise InputError("give either a result_id or xyz_m and ypr_deg, not both", "result_id")
        return from_xyz_ypr(_numbers(xyz_m, 3, "xyz_m", "m"), np.radians(_numbers(ypr_deg, 3, "ypr_deg", "deg")))
    if result_id is not None:
        return service.result_transform(session, lidar, result_id)
    return session.rig.T_a_b(camera, lidar)


@router.get("/lidar-camera/overlay/{image_id}", responses={200: {"content": {"image/jpeg": {}}}})
def overlay(
    image_id: str, camera: str, lidar: str, session: deps.SessionDep,
    result_id: Annotated[str | None, Query(description="draw with this result's T_camera_lidar; default the rig's")]
    = None,
    xyz_m: Annotated[str | None, Query(description="draw with this T_camera_lidar: translation 'x,y,z' (m)")] = None,
    ypr_deg: Annotated[str | None, Query(description="... and ROS 'yaw,pitch,roll' (deg)")] = None,
    cloud_id: Annotated[str | None, Query(description="draw this cloud capture of the LiDAR on the image capture "
                                                      "(any two captures); default the image's stored pair")] = None,
    colour_by: Annotated[Literal[COLOUR_MODES], Query(description="point colours")] = "depth",
    range_m: Annotated[str | None, Query(description="range window 'lo,hi' (m) from the LiDAR")] = None,
    occlusion_px: Annotated[int, Query(ge=0, le=64, description="occlusion filter block (px); 0: off")] = 6,
    radius_px: Annotated[int, Query(ge=0, le=8, description="point square's half side (px)")] = 1,
    legend: Annotated[bool, Query(description="add the colour scale's legend beneath the image")] = False,
) -> Response:
    """One image with the LiDAR's cloud drawn on it at the image's full size, as a JPEG.

    The headers ``X-Colour-Scale`` (what the colours mean, e.g. ``depth (m)``), ``X-Colour-Range`` (``lo,hi`` at the
    colour map's ends: for depth the 2nd-98th percentile of the drawn points' depths) and ``X-Points-Drawn`` say
    what was drawn.
    """
    intrinsics = service.camera_intrinsics(session, camera)
    if intrinsics.width * intrinsics.height > MAX_IMAGE_PIXELS.value():
        raise InputError(f"{camera}'s images are {intrinsics.width}x{intrinsics.height} px, more than "
                         f"{MAX_IMAGE_PIXELS.describe()}", camera, status_code=413)
    T_camera_lidar = _overlay_transform(session, camera, lidar, result_id, xyz_m, ypr_deg)
    window = OverlayStyle.range_m if range_m is None else tuple(_numbers(range_m, 2, "range_m", "m"))
    if not 0 <= window[0] < window[1]:
        raise InputError(f"expected a range window 'lo,hi' with 0 <= lo < hi (m), got {range_m!r}", "range_m")
    style = OverlayStyle(colour_by=colour_by, range_m=window, occlusion_px=occlusion_px, radius_px=radius_px)
    scene = service.overlay_scene(session, camera, lidar, image_id, cloud_id)
    (drawn,), (projection,), scale = service.render_scenes(session, camera, lidar, [scene], T_camera_lidar, style)
    headers = {"X-Colour-Scale": scale.label, "X-Colour-Range": f"{scale.lo:.6g},{scale.hi:.6g}",
               "X-Points-Drawn": str(len(projection)), "Cache-Control": "no-store"}
    return Response(encode_jpeg(with_legend(drawn, scale) if legend else drawn), media_type="image/jpeg",
                    headers=headers)


@router.get("/lidar-camera/view", response_class=HTMLResponse)
def overlay_view(session: deps.SessionDep) -> HTMLResponse:
    """The full-size overlay page of an existing session (zoom with the wheel, pan by dragging). Its query is the
    overlay's (``camera``, ``lidar``, ``xyz_m``, ``ypr_deg``, ``colour_by``, ``range_m``, ``occlusion_px``,
    ``radius_px``) and ``scene``: an image capture id (with ``cloud_id`` for two captures that are not a stored pair)
    or ``all``."""
    return HTMLResponse(VIEW_PAGE.read_text(), headers={"Cache-Control": "no-store"})


@router.get("/results/{result_id}/files/{file_name}")
def result_file(result_id: str, file_name: str, session: deps.SessionDep) -> FileResponse:
    """A file stored with a result, e.g. ``overlay_before.jpg`` and ``overlay_after.jpg`` of a LiDAR-camera solve."""
    return FileResponse(session.result_file(result_id, file_name))
