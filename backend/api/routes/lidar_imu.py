"""LiDAR-IMU calibration from the LiDAR's captures and an uploaded IMU recording: the rotation and the time offset,
kept and accepted as the rig's LiDAR-IMU edge (the translation stays the mounting guess) and the IMU's clock offset."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Form, UploadFile

from backend.api.routes import deps
from backend.api.schemas import JobStatus
from backend.api.uploads import UploadRoute, read_csv_upload, upload_limit
from backend.calib.lidar_imu import service
from backend.core.limits import MAX_TABLE_MB

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}/lidar-imu", tags=["lidar-imu"], route_class=UploadRoute)


@router.post("", status_code=202, response_model=JobStatus)
@upload_limit(MAX_TABLE_MB, "imu")
def solve(sensor: str, session: deps.SessionDep, jobs: deps.JobsDep,
          lidar: Annotated[str, Form(max_length=64, description="the LiDAR whose captures were taken while the rig "
                                                                "turned in a static scene")],
          imu: Annotated[UploadFile, File(description="IMU samples: CSV t_ns,wx,wy,wz,ax,ay,az")]) -> dict[str, Any]:
    """Solve ``R_lidar_imu`` and the time offset (``t_imu = t_lidar + offset``) in the background from the LiDAR's
    captures (their time stamps on the LiDAR's clock) and the IMU's samples; the file and the sensors are checked
    first (a 4xx names the one at fault). Poll ``/api/jobs/{id}`` for ``result_id``; accept it with
    ``POST /api/sessions/{name}/accept``."""
    imu_csv = read_csv_upload(imu, "imu")
    service.read_session_inputs(session, sensor, lidar, imu_csv)  # fail fast, before queueing
    job = jobs.submit(f"LiDAR-IMU of {lidar} and {sensor}", lambda progress: service.solve_session(
        session, sensor, lidar, imu_csv, progress))
    return job.status() | {"result_id": None}


@router.get("")
def results(sensor: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    """The IMU's LiDAR-IMU results, oldest first: the ``lidar-imu`` command's JSON for each, with its id."""
    return service.lidar_imu_results(session, sensor)
