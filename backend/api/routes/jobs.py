"""Background job status and cancel."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from backend.api.routes import deps
from backend.api.schemas import JobStatus
from backend.services.jobs import Job

router = APIRouter(prefix="/jobs", tags=["jobs"])


def job_status(job: Job) -> dict[str, Any]:
    """A job's state with its outcome: a stored result's id, or the summary of a job that makes no one result."""
    return job.status() | {"result_id": job.result if isinstance(job.result, str) else None,
                           "summary": job.result if isinstance(job.result, dict) else None}


@router.get("/{job_id}", response_model=JobStatus)
def get_job(job_id: str, jobs: deps.JobsDep) -> dict[str, Any]:
    return job_status(jobs.get(job_id))


@router.post("/{job_id}/cancel", response_model=JobStatus)
def cancel_job(job_id: str, jobs: deps.JobsDep) -> dict[str, Any]:
    job = jobs.get(job_id)
    job.cancel()
    return job_status(job)
