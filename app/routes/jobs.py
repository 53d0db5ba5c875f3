"""`/v1/jobs`: submit, list, poll, result, artifacts, delete."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import FileResponse, JSONResponse

from app import jobs, results
from app.deps import FastJobDep, JobDep, OwnerDep, ProducerDep, SettingsDep, StoreDep
from app.errors import ApiError
from app.schemas import DeleteResult, ErrorBody, JobList, JobResult, JobStatus

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 413, 415, 422, 503)}
_UPLOAD_ERRORS: dict[int | str, dict[str, Any]] = {
    **_ERRORS, **{code: {"model": ErrorBody} for code in (400, 507)}}

_UPLOAD_BODY: dict[str, Any] = {
    "requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
        "type": "object", "required": ["images"],
        "properties": {
            "images": {"type": "array", "items": {"type": "string", "format": "binary"},
                       "description": "3-10 photos (JPEG, PNG or WebP) in walking order."},
            "masks": {"type": "array", "items": {"type": "string", "format": "binary"},
                      "description": "Optional: one mask per photo, same order and size."},
            "config": {"type": "string",
                       "description": 'JSON: {"preset": "preview", "overrides": {...}}'},
            "webhook_url": {"type": "string", "format": "uri",
                            "description": "Called with a signed JSON body when done."},
        }}}}}}


@router.post("", status_code=202, response_model=JobStatus, responses=_UPLOAD_ERRORS,
             openapi_extra=_UPLOAD_BODY, summary="Submit ordered photos as a new job")
async def create_job(request: Request, settings: SettingsDep, store: StoreDep,
                     producer: ProducerDep, owner: OwnerDep) -> JSONResponse:
    """Accept 3-10 ordered photos (and optional masks and config); queue the job."""
    record = await jobs.submit(request, settings, store, producer, owner)
    body = jobs.to_status(record).model_dump(mode="json")
    return JSONResponse(body, status_code=202, headers={"Location": body["links"]["self"]})


@router.get("", response_model=JobList, responses=_ERRORS, summary="The caller's jobs")
def list_jobs(store: StoreDep, owner: OwnerDep,
              limit: Annotated[int, Query(ge=1, le=100)] = 20,
              offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0) -> JobList:
    """Jobs newest first, one page at a time."""
    records, total = store.list(owner, offset, limit)
    following = offset + limit
    next_url = f"/v1/jobs?limit={limit}&offset={following}" if following < total else None
    return JobList(items=[jobs.to_status(r) for r in records], total=total, limit=limit,
                   offset=offset, next=next_url)


@router.get("/{job_id}", response_model=JobStatus, responses=_ERRORS, summary="Job status")
async def get_job(job: FastJobDep) -> JobStatus:
    """State, stage, progress, ETA, timestamps and error of one job."""
    return jobs.to_status(job)


@router.get("/{job_id}/result", response_model=JobResult, responses=_ERRORS,
            summary="Result of a succeeded job")
def get_result(job: JobDep, store: StoreDep) -> JobResult:
    """Retrieved model, per-photo poses and IoU, discarded photos, metrics, artifact links."""
    return results.read_result(job, store.job_dir(job.id))


@router.get("/{job_id}/artifacts/{name:path}", responses=_ERRORS, response_class=FileResponse,
            summary="Download an artifact (range requests supported)")
def get_artifact(job: JobDep, store: StoreDep, name: str) -> FileResponse:
    """orbit.mp4, orbit.gif, mesh.glb, poses.json, transforms.json, metrics.json, views/NNN.png."""
    if job.state != "succeeded":
        raise ApiError(409, "not_ready", f"the job is {job.state.value}",
                       hint="artifacts exist once the job has succeeded")
    path = results.artifact_path(store.job_dir(job.id), name)
    download = None if path.suffix in (".mp4", ".gif", ".png") else path.name
    return FileResponse(path, media_type=results.media_type(path), filename=download,
                        content_disposition_type="attachment")


@router.delete("/{job_id}", response_model=DeleteResult, responses=_ERRORS,
               summary="Cancel (if running) and delete a job")
def delete_job(job: JobDep, store: StoreDep) -> DeleteResult:
    """A running job stops at its next step; then its files are removed."""
    return jobs.delete_job(store, job)
