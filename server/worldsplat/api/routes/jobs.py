"""The job routes: a job's state, cancelling it (kept readable) or deleting it, and its progress events."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import StreamingResponse

from ..openapi import JOB_LINKS, SSE, errors, ok
from ..schemas import JobOut
from ..state import Pg, job_view
from ..streaming import sse_job

router = APIRouter(tags=["jobs"])


@router.get("/api/jobs/{job_id}", response_model=None, responses={200: ok(JobOut, links=JOB_LINKS), **errors(404)})
def job_status(job_id: str, pg: Pg) -> dict:
    return job_view(pg.get_job(job_id))


@router.delete(
    "/api/jobs/{job_id}",
    response_model=None,
    responses={
        200: ok(
            JobOut,
            "the job as it was deleted (cancelled, cancelling, or already finished); "
            "the job's routes answer 404 from then on",
        ),
        **errors(404),
    },
)
def job_cancel(job_id: str, pg: Pg) -> dict:
    pg.get_job(job_id)
    return job_view(pg.jobs.delete(job_id))


@router.post(
    "/api/jobs/{job_id}/cancel",
    response_model=None,
    responses={
        200: ok(JobOut, "the job (cancelled, cancelling, or already finished); it stays readable"),
        **errors(400, 404, 413),
    },
)
def job_cancel_post(job_id: str, pg: Pg) -> dict:
    pg.get_job(job_id)
    return job_view(pg.jobs.cancel(job_id))


@router.get("/api/jobs/{job_id}/events", response_class=StreamingResponse, responses={**SSE, **errors(404)})
async def job_events(job_id: str, request: Request, pg: Pg):
    return sse_job(pg.jobs, pg.get_job(job_id).id, request)
