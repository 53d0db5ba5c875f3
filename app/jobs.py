"""Job life cycle on the API side: accept an upload, show state, cancel and delete, clean up."""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
import time
import uuid
from collections.abc import Sequence
from pathlib import Path

import redis
from celery import Celery
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from app.core import StorageError
from app.errors import ApiError, store_unavailable
from app.multipart import Limits as UploadLimits
from app.multipart import receive_form
from app.queue import enqueue
from app.schemas import DeleteResult, JobLinks, JobStatus
from app.settings import Settings
from app.state import (
    AsyncJobReader,
    JobRecord,
    JobState,
    JobStore,
    Limits,
    QueueEstimate,
    Refusal,
    default_preset,
    serving_device,
    stage_work,
)
from app.uploads import lay_out

log = logging.getLogger(__name__)

TMP_PREFIX = ".upload-"  # staging folders of uploads in progress, inside the data root
STAGING_MAX_AGE_S = 3600.0
ACTIVE = (JobState.queued, JobState.running)


def links(job_id: str) -> JobLinks:
    """URLs of a job's status, result and web view."""
    return JobLinks(self=f"/v1/jobs/{job_id}", result=f"/v1/jobs/{job_id}/result",
                    web=f"/?job={job_id}")


def to_status(record: JobRecord, queue: QueueEstimate | None = None) -> JobStatus:
    """The public view of a job record.

    Args:
        record: the job.
        queue: where the job stands in the queue (``queue_estimate``); used only while it is
            queued, and then gives ``queue_position`` and ``eta_s``.
    """
    estimate = queue if record.state == JobState.queued else None
    return JobStatus(id=record.id, state=record.state, preset=record.preset,
                     n_photos=record.n_photos, created_at=record.created_at,
                     links=links(record.id), stage=record.stage,
                     progress=min(max(record.progress, 0.0), 1.0),
                     eta_s=record.eta_s if estimate is None else estimate.eta_s,
                     queue_position=None if estimate is None else estimate.position,
                     started_at=record.started_at, finished_at=record.finished_at,
                     error=record.error, error_detail=record.error_detail)


def queue_estimate(store: JobStore, record: JobRecord, settings: Settings) -> QueueEstimate | None:
    """Where a queued job stands (none for other states); None if unknown.

    Best effort: a Redis error leaves the status without a queue position rather than failing.
    """
    if record.state != JobState.queued:
        return None
    try:
        return store.queue_estimates([record.id], settings.device).get(record.id)
    except redis.RedisError as exc:
        log.warning("queue estimate of job %s failed: %s", record.id, exc)
        return None


async def queue_estimate_fast(reader: AsyncJobReader, record: JobRecord) -> QueueEstimate | None:
    """``queue_estimate`` on the asyncio reader of the polling route (no thread hop)."""
    try:
        return await reader.queue_estimate(record)
    except redis.RedisError as exc:
        log.warning("queue estimate of job %s failed: %s", record.id, exc)
        return None


def statuses(store: JobStore, records: Sequence[JobRecord], settings: Settings
             ) -> list[JobStatus]:
    """Public views of several jobs; the queued ones' estimates in one round trip."""
    queued = [r.id for r in records if r.state == JobState.queued]
    estimates: dict[str, QueueEstimate] = {}
    if queued:
        try:
            estimates = store.queue_estimates(queued, settings.device)
        except redis.RedisError as exc:
            log.warning("queue estimates failed: %s", exc)
    return [to_status(r, estimates.get(r.id)) for r in records]


async def submit(request: Request, settings: Settings, store: JobStore, producer: Celery,
                 owner: str) -> JobRecord:
    """Receive, validate and store an upload as a new job folder, then queue it.

    The upload is built in a staging folder inside the data root and renamed into place only
    once complete, so a rejected or interrupted upload leaves no half job folder. With object
    storage the folder then goes to the store before the job is queued, and only the store
    keeps it.

    Args:
        request: the multipart request.
        settings: limits and defaults.
        store: job state.
        producer: the Celery app used to send the task.
        owner: hash of the caller's API key (or the anonymous owner).

    Returns:
        The queued job's record.
    """
    refusal = await run_in_threadpool(store.usage.admit, owner, Limits.of(settings),
                                      settings.retention_days * 86400)
    if refusal is not None:  # before the body is read: nothing is stored
        raise limit_error(refusal)
    staging = settings.data_root / f"{TMP_PREFIX}{uuid.uuid4().hex}"
    limits = UploadLimits(settings.max_file_bytes, settings.max_total_bytes, settings.max_photos)
    job_id = ""
    try:
        settings.data_root.mkdir(parents=True, exist_ok=True)
        staging.mkdir()
        form = await receive_form(request, staging, limits)
        def preset() -> str:  # asked only when the config names no preset
            return default_preset(settings, serving_device(store.workers, settings.device))

        spec = await run_in_threadpool(lay_out, form, staging, settings, preset)
        job_id = str(uuid.uuid4())
        os.rename(staging, store.job_dir(job_id))
        await run_in_threadpool(store.storage.push, job_id, store.job_dir(job_id))
        store.storage.release(store.job_dir(job_id))  # object storage: the store has it now
    except OSError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        if job_id:
            await run_in_threadpool(store.remove_folder, job_id)
        raise storage_error(exc) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    record = JobRecord(id=job_id, preset=spec.preset, n_photos=len(spec.names), names=spec.names,
                       owner=owner, created_at=time.time(), webhook_url=spec.webhook_url,
                       work=stage_work(spec.config))
    await run_in_threadpool(_store_and_enqueue, store, producer, record)
    return record


def limit_error(refusal: Refusal) -> ApiError:
    """429 (a per-key limit) or 503 (the queue is full), naming the limit, the use and when
    it frees up, in the body and in `Retry-After`."""
    code = "queue_full" if refusal.status == 503 else "limit_reached"
    hint = (f"try again in {refusal.retry_after_s} s; GET /v1/usage shows this key's use"
            if refusal.status == 429 else f"try again in {refusal.retry_after_s} s")
    error = ApiError(refusal.status, code, refusal.message, hint=hint,
                     headers={"Retry-After": str(refusal.retry_after_s)})
    error.detail = error.detail.model_copy(update={
        "limit": refusal.limit, "maximum": refusal.maximum, "current": refusal.current,
        "retry_after_s": refusal.retry_after_s})
    return error


def storage_error(exc: OSError) -> ApiError:
    """507 when the job storage is full, else 503 (the storage is missing or broken)."""
    log.error("job storage error: %s", exc)
    if isinstance(exc, StorageError):  # the object store: its details are for the operator
        return ApiError(503, "storage_unavailable", "the job storage cannot be reached",
                        hint="try again later; the operator has to check the object store",
                        headers={"Retry-After": "30"})
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return ApiError(507, "storage_full", "the server has no room left to store the upload",
                        hint="try again later, or send smaller photos",
                        headers={"Retry-After": "300"})
    return ApiError(503, "storage_unavailable",
                    f"the job storage cannot be written ({exc.strerror or type(exc).__name__})",
                    hint="try again later; the operator has to check the data root",
                    headers={"Retry-After": "30"})


def _store_and_enqueue(store: JobStore, producer: Celery, record: JobRecord) -> None:
    try:
        store.create(record)
    except redis.RedisError as exc:
        log.error("could not store job %s: %s", record.id, exc)
        store.remove_folder(record.id)
        with contextlib.suppress(redis.RedisError):  # whatever part of the record got in
            store.delete(record)
        raise store_unavailable() from None
    try:
        enqueue(producer, record.id)
    except Exception as exc:
        log.error("could not queue job %s: %s", record.id, exc)
        store.delete(record)
        raise ApiError(503, "queue_unavailable", "the job queue is not reachable",
                       hint="try again in a minute", headers={"Retry-After": "30"}) from None


def delete_job(store: JobStore, record: JobRecord, wait_s: float = 5.0) -> DeleteResult:
    """Cancel a job if it is queued or running, then delete its state and folder.

    A running job's worker reads the cancel flag between steps; this waits up to ``wait_s``
    for it to acknowledge (``worker_stopped``). Either way the folder is renamed away and
    removed before the answer (``JobStore.delete``), and no writer re-creates a missing job
    folder, so a worker still inside a step can no longer write the job's files.
    """
    previous = record.state
    stopped = True
    if previous in ACTIVE:
        store.cancel(record.id)
        stopped = wait_until_stopped(store, record.id, wait_s)
    store.delete(record)
    return DeleteResult(id=record.id, deleted=True, previous_state=previous,
                        worker_stopped=stopped)


def wait_until_stopped(store: JobStore, job_id: str, wait_s: float) -> bool:
    """Poll until the job is no longer running; False on timeout."""
    deadline = time.monotonic() + wait_s
    while True:
        current = store.get(job_id)
        if current is None or current.state.terminal:
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.2)


def cleanup(store: JobStore, retention_s: float, now: float | None = None) -> int:
    """Remove jobs older than the retention period; re-seed Redis from state.json on the way.

    Args:
        store: job state.
        retention_s: age (since finishing, or creation if unfinished) after which a job goes.
        now: the current time (default: ``time.time()``).

    Returns:
        How many job folders were removed.
    """
    now = time.time() if now is None else now
    removed = 0
    for job_id in _oldest_first(store):
        record = store.get(job_id)  # re-seeds Redis when it lost the job
        if record is None:
            removed += _remove_orphan(store, job_id, now, retention_s)
            continue
        reference = record.finished_at or record.created_at
        if record.state != JobState.running and now - reference > retention_s:
            store.delete(record)
            removed += 1
    _remove_stale_staging(store.data_root, now)
    store.remove_trash()
    return removed


def _oldest_first(store: JobStore) -> list[str]:
    """Job ids by creation time (from state.json), so jobs Redis lost are re-seeded into the
    queue in the order they came, each owner's keeping its own order."""
    def created(job_id: str) -> float:
        record = store.read_state_file(job_id)
        return record.created_at if record is not None else 0.0

    return sorted(store.iter_job_ids(), key=created)


def _remove_orphan(store: JobStore, job_id: str, now: float, retention_s: float) -> int:
    """Remove data no record owns: at once when the job was deleted (what a late writer left),
    else once it is older than the retention period."""
    written = store.last_written(job_id)
    if written is None:
        return 0
    if store.tombstoned(job_id) or now - written > retention_s:
        store.remove_folder(job_id)
        return 1
    return 0


def _remove_stale_staging(root: Path, now: float) -> None:
    if not root.is_dir():
        return
    for entry in root.glob(f"{TMP_PREFIX}*"):
        try:
            if now - entry.stat().st_mtime > STAGING_MAX_AGE_S:
                shutil.rmtree(entry, ignore_errors=True)
        except OSError:
            continue
