"""Camera-IMU calibration from an uploaded recording: the extrinsic and the time offset, kept and accepted as the
rig's camera-IMU edge."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, File, Form, UploadFile

from backend.api.routes import deps
from backend.api.schemas import JobStatus
from backend.api.uploads import UploadRoute, read_csv_upload, upload_limit
from backend.calib.camera_imu import service
from backend.calib.camera_imu.service import CameraImuSettings
from backend.core.limits import MAX_TABLE_MB

router = APIRouter(prefix="/sessions/{name}/sensors/{sensor}/camera-imu", tags=["camera-imu"],
                   route_class=UploadRoute)


@router.post("", status_code=202, response_model=JobStatus)
@upload_limit(MAX_TABLE_MB, "imu")
def solve(sensor: str, session: deps.SessionDep, jobs: deps.JobsDep,
          camera: Annotated[str, Form(max_length=64, description="the camera that saw the board")],
          board: Annotated[str, Form(max_length=200, description="the board, e.g. aprilgrid:6x6:0.088:0.3")],
          imu: Annotated[UploadFile, File(description="IMU samples: CSV t_ns,wx,wy,wz,ax,ay,az")],
          detections: Annotated[UploadFile, File(description="the board's corners: CSV t_ns,u_px,v_px,x_m,y_m,"
                                                             "z_m,tag_id,corner")],
          imu_model: Annotated[Literal[service.IMU_MODELS], Form(
              description="the IMU's model (Kalibr's names): calibrated, or scale-misalignment to fit the axes' "
                          "scale and misalignment too")] = "calibrated") -> dict[str, Any]:
    """Solve ``T_camera_imu`` and the time offset (``t_imu = t_cam + offset``) in the background, through the
    camera's intrinsics in the rig; the files are checked first (a 422 names the one at fault), then kept with the
    result. Poll ``/api/jobs/{id}`` for ``result_id``; accept it with ``POST /api/sessions/{name}/accept``."""
    imu_csv, detections_csv = read_csv_upload(imu, "imu"), read_csv_upload(detections, "detections")
    service.read_recording(session, sensor, camera, imu_csv, detections_csv, board)  # fail fast, before queueing
    job = jobs.submit(f"camera-IMU of {camera} and {sensor}", lambda progress: service.solve_session(
        session, sensor, camera, imu_csv, detections_csv, board, CameraImuSettings(imu_model=imu_model),
        progress=progress))
    return job.status() | {"result_id": None}


@router.get("")
def results(sensor: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    """The IMU's camera-IMU results, oldest first: the ``camera-imu`` command's JSON for each, with its id."""
    return service.camera_imu_results(session, sensor)
