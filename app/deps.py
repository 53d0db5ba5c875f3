"""Request dependencies, as ``Annotated`` aliases the routes declare.

The non-blocking ones are ``async`` so the polling route never waits for a worker thread.
"""

from __future__ import annotations

import hmac
import logging
from typing import Annotated

import redis
from celery import Celery
from fastapi import Depends, Path, Request, Response, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool

from app.errors import ApiError, not_found, store_unavailable
from app.settings import Settings, hash_key
from app.state import ANON_OWNER, AsyncJobReader, JobRecord, JobStore, is_job_id

log = logging.getLogger(__name__)

STATE_SOURCE_HEADER = "X-Job-State-Source"
"""Set to ``disk`` when a job was read from its state.json because Redis did not answer."""

_bearer = HTTPBearer(auto_error=False, description="An API key, when the server requires one.")


async def get_settings(request: Request) -> Settings:
    """The app's settings."""
    settings: Settings = request.app.state.settings
    return settings


async def get_store(request: Request) -> JobStore:
    """The job store."""
    store: JobStore = request.app.state.store
    return store


async def get_producer(request: Request) -> Celery:
    """The Celery app used to send tasks."""
    producer: Celery = request.app.state.producer
    return producer


async def get_reader(request: Request) -> AsyncJobReader:
    """The polling route's asyncio reader."""
    reader: AsyncJobReader = request.app.state.reader
    return reader


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[JobStore, Depends(get_store)]
ReaderDep = Annotated[AsyncJobReader, Depends(get_reader)]
ProducerDep = Annotated[Celery, Depends(get_producer)]


async def get_owner(settings: SettingsDep,
              credentials: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)]
              ) -> str:
    """The caller's identity: the hash of its API key, or the anonymous owner on an open server.

    Raises:
        ApiError: 401 when keys are configured and the request carries no valid one.
    """
    if not settings.api_key_hashes:
        return ANON_OWNER
    challenge = {"WWW-Authenticate": "Bearer"}
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise ApiError(401, "unauthorized", "an API key is required",
                       hint="send the header `Authorization: Bearer <key>`", headers=challenge)
    digest = hash_key(credentials.credentials)
    if not any(hmac.compare_digest(digest, known) for known in settings.api_key_hashes):
        raise ApiError(401, "unauthorized", "the API key is not valid",
                       hint="check the key with the service's operator", headers=challenge)
    return digest


OwnerDep = Annotated[str, Depends(get_owner)]


def _from_disk(store: JobStore, job_id: str, response: Response,
               exc: redis.RedisError) -> JobRecord:
    """The job as its folder's state.json has it, while Redis does not answer.

    state.json is written before Redis on every final state (worker.runner._finish) and
    mirrored every few seconds while the job runs, so a finished job reads exactly as it was;
    a queued or running one shows its last mirrored stage and progress (marked by the
    ``X-Job-State-Source: disk`` header). Without a readable state.json the job's existence
    cannot be told: the usual 503.
    """
    record = store.read_state_file(job_id) if is_job_id(job_id) else None
    if record is None:
        log.warning("Redis unavailable and no state.json for job %s: %s", job_id, exc)
        raise store_unavailable() from exc
    log.info("Redis unavailable (%s); job %s read from state.json", exc, job_id)
    response.headers[STATE_SOURCE_HEADER] = "disk"
    return record


def _check_owner(record: JobRecord | None, owner: str) -> JobRecord:
    """The record when the caller owns it; 404 for unknown ids and other callers' jobs alike."""
    if record is None or not hmac.compare_digest(record.owner, owner):
        raise not_found()
    return record


def get_job(job_id: Annotated[str, Path(max_length=64, description="The job's id.")],
            store: StoreDep, owner: OwnerDep, response: Response) -> JobRecord:
    """The caller's job; 404 for unknown ids and for other callers' jobs alike.

    Redis down: read from state.json (same owner check); 503 only when that fails too.
    """
    try:
        record = store.get(job_id)
    except redis.RedisError as exc:
        record = _from_disk(store, job_id, response, exc)
    return _check_owner(record, owner)


JobDep = Annotated[JobRecord, Depends(get_job)]


async def get_job_fast(job_id: Annotated[str, Path(max_length=64, description="The job's id.")],
                       reader: ReaderDep, store: StoreDep, owner: OwnerDep,
                       response: Response) -> JobRecord:
    """Like ``get_job``, but one asyncio HGETALL (no thread hop) when Redis has the job."""
    if not is_job_id(job_id):
        raise not_found()
    try:
        record = (await reader.get(job_id)
                  or await run_in_threadpool(store.get, job_id))  # state.json fallback
    except redis.RedisError as exc:
        record = await run_in_threadpool(_from_disk, store, job_id, response, exc)
    return _check_owner(record, owner)


FastJobDep = Annotated[JobRecord, Depends(get_job_fast)]
