"""Recordings (ROS bags, Velodyne pcaps, Livox .lvx, cloud folders): list a bag's topics, import a recording as
captures; a static LiDAR's frames accumulated over an integration time as one capture; sensors recorded together
live, every frame, for their time offset."""

from __future__ import annotations

import dataclasses
from typing import Any

from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from backend.api.routes import deps
from backend.api.schemas import JobStatus, RecordingImportRequest
from backend.services import accumulated_capture as accumulated
from backend.services import motion_recording
from backend.services import recordings as service

router = APIRouter(tags=["recordings"])


@router.get("/recordings/topics")
def bag_topics(path: str = Query(..., description="a ROS 2 bag folder, .mcap or .db3 on the server's disk")
               ) -> list[dict[str, Any]]:
    """The bag's topics with message type, count, time span and whether they can be replayed."""
    return [topic.to_dict() for topic in service.bag_topics(path)]


@router.post("/sessions/{name}/sensors/{sensor}/import", status_code=202, response_model=JobStatus)
def import_recording(sensor: str, body: RecordingImportRequest, session: deps.SessionDep,
                     jobs: deps.JobsDep) -> dict[str, Any]:
    """Import every ``every``-th scan of a recording in the background; the job's ``summary`` lists the captures."""
    settings = service.recording_settings(session, sensor, body.device)  # fail fast, before queueing
    job = jobs.submit(f"import into {sensor}", lambda progress: service.import_recording(
        session, sensor, settings, every=body.every, limit=body.limit, progress=progress).to_dict())
    return job.status() | {"result_id": None, "summary": None}


class AccumulateRequest(BaseModel):
    integration_s: float = Field(gt=0, le=60, description="seconds of the sensor's own time to add up (a static "
                                                          "sensor: a Livox fills its field of view in about 0.5 s)")


@router.post("/sessions/{name}/sensors/{sensor}/accumulate", status_code=202, response_model=JobStatus)
def accumulate(sensor: str, body: AccumulateRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Read the LiDAR's device for ``integration_s`` and keep the accumulated cloud as one capture, in the
    background; the job's ``summary`` has the capture, its coverage of the field of view (0..1) and its frames."""
    accumulated.check_device(session, sensor)  # fail fast, before queueing
    job = jobs.submit(f"accumulate {sensor}", lambda progress: accumulated.capture_accumulated(
        session, sensor, body.integration_s, progress).to_dict())
    return job.status() | {"result_id": None, "summary": None}


class MotionRecordingRequest(BaseModel):
    sensors: list[str] = Field(min_length=1, max_length=8, description="the sensors to record together (cameras "
                                                                        "and LiDARs with capture devices)")
    duration_s: float = Field(gt=0, le=motion_recording.MAX_DURATION_S, description="seconds to record, from when "
                                                                                    "every device has answered")


@router.post("/sessions/{name}/recordings", status_code=202, response_model=JobStatus)
def record_motion(body: MotionRecordingRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Record the sensors together, every frame, in the background (a board carried through their views, for
    their time offset); the job's ``summary`` has the recording's ``name`` (``recording`` of a time-offset
    request), the captures ``stored``, the camera frames ``missed`` (no board) and the captures a second
    ``rates_hz`` per sensor, and ``duration_s``."""
    motion_recording.check_recording(session, body.sensors, body.duration_s)  # fail fast, before queueing
    job = jobs.submit(f"recording {', '.join(body.sensors)}", lambda progress: dataclasses.asdict(
        motion_recording.record_motion(session, body.sensors, body.duration_s, progress)))
    return job.status() | {"result_id": None, "summary": None}


@router.get("/sessions/{name}/sensors/{sensor}/recordings")
def sensor_recordings(sensor: str, session: deps.SessionDep) -> list[str]:
    """The names of the recordings holding captures of the sensor, newest first."""
    session.rig.get(sensor)
    return motion_recording.recordings(session, sensor)
