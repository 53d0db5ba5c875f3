"""`/v1/jobs`: submit, list, poll, result, artifacts, delete."""

from __future__ import annotations

import os
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import FileResponse, JSONResponse
from starlette.responses import MalformedRangeHeader, RangeNotSatisfiable

from app import jobs, results
from app.deps import (
    FastJobDep,
    JobDep,
    OwnerDep,
    ProducerDep,
    ReaderDep,
    SettingsDep,
    StoreDep,
)
from app.errors import ApiError
from app.schemas import (
    DeleteResult,
    ErrorBody,
    JobList,
    JobResult,
    JobStatus,
    job_create_schema,
)

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 413, 415, 422, 503)}
_ARTIFACT_ERRORS: dict[int | str, dict[str, Any]] = {
    **_ERRORS, 304: {"description": "Not modified (`If-None-Match` matched the ETag)."},
    **{code: {"model": ErrorBody} for code in (400, 416)}}
_UPLOAD_ERRORS: dict[int | str, dict[str, Any]] = {
    **_ERRORS, **{code: {"model": ErrorBody} for code in (400, 408, 429, 507)}}

_UPLOAD_BODY: dict[str, Any] = {
    "requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
        "type": "object", "required": ["images"],
        "properties": {
            "images": {"type": "array", "items": {"type": "string", "format": "binary"},
                       "description": "3-10 photos (JPEG, PNG, WebP, HEIC or AVIF) in walking "
                                      "order."},
            "masks": {"type": "array", "items": {"type": "string", "format": "binary"},
                      "description": "Optional: one mask per photo, same order and size."},
            "config": {**job_create_schema(),
                       "description": 'JSON: {"preset": "preview", "overrides": {...}}; '
                                      "the settings a client may send are `overrides`'s."},
            "webhook_url": {"type": "string", "format": "uri",
                            "description": "Called with a signed JSON body when done."},
        }}, "encoding": {"config": {"contentType": "application/json"}}}}}}


@router.post("", status_code=202, response_model=JobStatus, responses=_UPLOAD_ERRORS,
             openapi_extra=_UPLOAD_BODY, summary="Submit ordered photos as a new job")
async def create_job(request: Request, settings: SettingsDep, store: StoreDep,
                     producer: ProducerDep, reader: ReaderDep, owner: OwnerDep) -> JSONResponse:
    """Accept 3-10 ordered photos (and optional masks and config); queue the job."""
    record = await jobs.submit(request, settings, store, producer, owner)
    queue = await jobs.queue_estimate_fast(reader, record)
    body = jobs.to_status(record, queue).model_dump(mode="json")
    return JSONResponse(body, status_code=202, headers={"Location": body["links"]["self"]})


@router.get("", response_model=JobList, responses=_ERRORS, summary="The caller's jobs")
def list_jobs(store: StoreDep, owner: OwnerDep, settings: SettingsDep,
              limit: Annotated[int, Query(ge=1, le=100)] = 20,
              offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0) -> JobList:
    """Jobs newest first, one page at a time."""
    records, total = store.page(owner, offset, limit)
    following = offset + limit
    next_url = f"/v1/jobs?limit={limit}&offset={following}" if following < total else None
    return JobList(items=jobs.statuses(store, records, settings), total=total, limit=limit,
                   offset=offset, next=next_url)


@router.get("/{job_id}", response_model=JobStatus, responses=_ERRORS, summary="Job status")
async def get_job(job: FastJobDep, reader: ReaderDep) -> JobStatus:
    """State, stage, progress, ETA, queue position, timestamps and error of one job."""
    queue = await jobs.queue_estimate_fast(reader, job)
    return jobs.to_status(job, queue)


@router.get("/{job_id}/result", response_model=JobResult, responses=_ERRORS,
            summary="Result of a succeeded job")
def get_result(job: JobDep, store: StoreDep) -> JobResult:
    """Retrieved model, per-photo poses and IoU, discarded photos, metrics, artifact links."""
    return results.read_result(job, results.results_folder(store, job))


ARTIFACT_CACHE_CONTROL = "private, max-age=86400, immutable"
"""A succeeded job's files are final: the worker writes them all before the job's state
becomes ``succeeded`` and nothing writes into the folder afterwards (it is only deleted)."""


def _etag_matches(if_none_match: str | None, etag: str) -> bool:
    """``If-None-Match`` (weak comparison, RFC 9110 13.1.2) against the artifact's ETag."""
    if not if_none_match:
        return False
    if if_none_match.strip() == "*":
        return True
    ours = etag.removeprefix("W/")
    return any(tag.strip().removeprefix("W/") == ours for tag in if_none_match.split(","))


def _check_range(request: Request, response: FileResponse, size: int) -> None:
    """Refuse, as the service's JSON errors, a Range header FileResponse would refuse.

    Mirrors FileResponse: Range counts only when If-Range is absent or names the current
    ETag or Last-Modified (otherwise the whole file is sent).
    """
    http_range = request.headers.get("range")
    if_range = request.headers.get("if-range")
    if http_range is None or (if_range is not None and if_range not in (
            response.headers["etag"], response.headers["last-modified"])):
        return
    try:
        FileResponse._parse_range_header(http_range, size)
    except RangeNotSatisfiable:
        raise ApiError(416, "range_not_satisfiable",
                       f"the range {http_range[:80]!r} lies outside the file ({size} bytes)",
                       hint="ask for bytes within the file's length, or drop the Range header",
                       headers={"Content-Range": f"bytes */{size}"}) from None
    except MalformedRangeHeader as exc:
        raise ApiError(400, "bad_range", f"the Range header is malformed: {exc.content}",
                       field="range", hint="send e.g. `Range: bytes=0-1023`") from None


@router.get("/{job_id}/artifacts/{name:path}", responses=_ARTIFACT_ERRORS,
            response_class=FileResponse,
            summary="Download an artifact (range requests and ETag revalidation supported)")
@router.head("/{job_id}/artifacts/{name:path}", responses=_ARTIFACT_ERRORS,
             response_class=FileResponse, summary="An artifact's headers, without its body")
def get_artifact(job: JobDep, store: StoreDep, name: str, request: Request) -> Response:
    """orbit.mp4, orbit.gif, mesh.glb, mesh.obj, results.zip, poses.json, transforms.json,
    sparse/0/cameras.txt, images/NNN_name.jpg, views/NNN.png, masks/NNN.png...

    Cached privately for a day and marked immutable (a succeeded job's files never change);
    `If-None-Match` with the ETag answers 304; HEAD answers the same headers without a body.
    """
    if job.state != "succeeded":
        raise ApiError(409, "not_ready", f"the job is {job.state.value}",
                       hint="artifacts exist once the job has succeeded")
    path = results.artifact_path(results.results_folder(store, job), name)
    download = None if path.suffix in (".mp4", ".gif", ".png", ".jpg") else path.name
    try:
        stat = os.stat(path)
    except OSError:  # the job was deleted since the check
        raise ApiError(404, "no_such_artifact", f"no artifact named {name[:80]!r}",
                       field="name", hint="see the result's `artifacts` for what exists") from None
    response = FileResponse(path, media_type=results.media_type(name), filename=download,
                            content_disposition_type="attachment", stat_result=stat,
                            headers={"Cache-Control": ARTIFACT_CACHE_CONTROL})
    if _etag_matches(request.headers.get("if-none-match"), response.headers["etag"]):
        return Response(status_code=304, headers={
            key: response.headers[key] for key in ("etag", "last-modified", "cache-control")})
    _check_range(request, response, stat.st_size)
    return response


@router.delete("/{job_id}", response_model=DeleteResult, responses=_ERRORS,
               summary="Cancel (if running) and delete a job")
def delete_job(job: JobDep, store: StoreDep, settings: SettingsDep) -> DeleteResult:
    """A running job stops at its next step; its files are removed before the answer, and no
    worker can write them again."""
    return jobs.delete_job(store, job, settings.delete_wait_s)
