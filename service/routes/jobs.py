"""Registrations that took longer than a request: their status, then the object."""

from __future__ import annotations

from fastapi import APIRouter

from service.deps import StateDep
from service.errors import ApiError, responses
from service.schemas import JobOut, JobProgress, ObjectCreated

router = APIRouter(tags=["objects"])


@router.get(
    "/jobs/{job_id}",
    response_model=JobOut,
    summary="A registration's status (running, done, failed), how far it is, and then its object",
    responses=responses(404, 422),
)
def get_job(job_id: str, state: StateDep) -> JobOut:
    job = state.jobs.get(job_id)
    if job is None:
        raise ApiError(404, f"no job {job_id}")
    result = ObjectCreated(**job.result) if job.result else None
    return JobOut(
        job_id=job.job_id,
        status=job.status,
        object_id=result.object_id if result else None,
        result=result,
        error=job.error,
        code=job.code if job.status == "failed" else None,
        progress=JobProgress(**job.progress) if job.progress else None,
    )
