"""What the task does with a job id: state transitions around one call of the core pipeline."""

from __future__ import annotations

import errno
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any, Protocol

import redis

from app.settings import Settings
from app.state import (
    FINISH_RETRY_S,
    HEARTBEAT_TTL_S,
    ErrorDetail,
    EtaModel,
    JobRecord,
    JobState,
    JobStore,
    finish_job,
    stage_work,
    unscaled,
)
from cadnerf_core.jobfolder import CONFIG, INPUTS, MASKS, JobFolder, StorageError, photo_index
from worker.progress import JobProgress
from worker.scratch import Scratch
from worker.shutdown import STOPPING
from worker.webhook import send_webhook

if TYPE_CHECKING:
    from cadnerf_core.library import Library

log = logging.getLogger(__name__)

DEFERRED = "deferred"  # queued jobs wait for their owner's running ones: the message comes back
HANDED_BACK = "handed_back"  # the worker is stopping: the job is queued again, its message too
UPLOAD_FIELDS = {INPUTS: "images", MASKS: "masks", CONFIG: "config"}  # job folder entry -> form
TIME_LIMIT_HINT = "choose a faster preset, or ask the operator for a longer time limit"

Outcome = tuple[JobState, str | None, ErrorDetail | None]  # final state, error, error detail


@lru_cache(maxsize=2)
def get_library(root: str) -> Library:
    """The CAD library, loaded once per worker process."""
    from cadnerf_core.library import load_library

    return load_library(Path(root))


def device_kind(device: str) -> str:
    """"cuda" or "cpu": the device a job will actually run on (for the ETA tables)."""
    if device != "auto":
        return device
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


class Claims(Protocol):
    """How a job is claimed for one worker (``worker.liveness.Liveness``)."""

    name: str

    def hold(self, job_id: str) -> bool:
        """Claim the job; False when another live worker holds it."""

    def drop(self, job_id: str) -> None:
        """Release the claim."""


class _FixedClaim:
    """Claims without a heartbeat to refresh them (tests, one-off runs): held for the hard limit."""

    def __init__(self, store: JobStore, ttl_s: float) -> None:
        self.store = store
        self.ttl_s = ttl_s
        self.name = f"{socket.gethostname()}-{os.getpid()}"

    def hold(self, job_id: str) -> bool:
        return self.store.claims.take(job_id, self.name, self.ttl_s)

    def drop(self, job_id: str) -> None:
        self.store.claims.release(job_id, self.name)


def execute(job_id: str, settings: Settings, store: JobStore,
            celery_update: Callable[[dict[str, Any]], None] | None = None,
            claims: Claims | None = None) -> dict[str, Any]:
    """Run the next job in fair order to a final state (a message is a wake-up token).

    Each queued job sent one message, so there are never fewer messages than queued jobs; the
    job run is the one ``JobStore.take_next`` hands out (round-robin across owners), which
    need not be the message's. A message for a job that is running again (delivered again
    after its worker died) resumes that job instead, unless a live worker holds it.

    Args:
        job_id: the message's job (its folder is ``settings.data_root / job_id``).
        settings: deployment settings (library, device, time limits, webhook secret).
        store: job state.
        celery_update: receives progress fields for Celery's custom state.
        claims: this worker's claims (default: one held for the hard time limit).

    Returns:
        ``{"id", "state", "error"}`` of the job run (a JSON-serialisable summary); state
        "duplicate" when another live worker holds the job (this delivery is dropped),
        ``DEFERRED`` when every queued job's owner is at ``max_running_per_key`` (the task
        sends the message again later), the message's job and its state when the queue was
        empty.
    """
    record = store.get(job_id)  # re-seeds the token's job when Redis lost it
    claims = claims or _FixedClaim(store, settings.job_hard_time_limit_s)
    if record is not None and record.state == JobState.running:
        return _resume(job_id, settings, store, celery_update, claims)
    taken = store.take_next(claims.name, HEARTBEAT_TTL_S, settings.max_running_per_key)
    if taken is None and settings.max_running_per_key and store.usage.queue_length():
        log.info("every queued job's owner runs its most jobs at once; asking again later")
        return {"id": job_id, "state": DEFERRED, "error": None}
    if taken is None:
        holder = store.claims.holder(job_id)
        if record is not None and holder not in (None, claims.name):
            log.warning("job %s is being run by %s; duplicate delivery dropped", job_id, holder)
            return {"id": job_id, "state": "duplicate", "error": None}
        log.info("job %s: nothing left in the queue", job_id)
        state = "missing" if record is None else record.state.value
        return {"id": job_id, "state": state, "error": None}
    if not claims.hold(taken):  # the claim just taken lapsed: another worker runs it now
        return {"id": taken, "state": "duplicate", "error": None}
    try:
        return _execute_claimed(taken, settings, store, celery_update, claims.name)
    finally:
        claims.drop(taken)


def _resume(job_id: str, settings: Settings, store: JobStore,
            celery_update: Callable[[dict[str, Any]], None] | None,
            claims: Claims) -> dict[str, Any]:
    """A message delivered again for a running job: resume it unless a live worker has it."""
    if not claims.hold(job_id):
        log.warning("job %s is being run by %s; duplicate delivery dropped", job_id,
                    store.claims.holder(job_id))
        return {"id": job_id, "state": "duplicate", "error": None}
    try:
        return _execute_claimed(job_id, settings, store, celery_update, claims.name)
    finally:
        claims.drop(job_id)


def _execute_claimed(job_id: str, settings: Settings, store: JobStore,
                     celery_update: Callable[[dict[str, Any]], None] | None,
                     worker: str) -> dict[str, Any]:
    record = store.get(job_id)  # again, now that no one else can change it under us
    if record is None or record.state.terminal:
        return {"id": job_id, "state": "missing" if record is None else record.state.value,
                "error": None}
    if store.cancel_requested(job_id):
        return _finish(store, settings, record, JobState.cancelled, None)
    started = record.started_at or time.time()
    taken = record.state == JobState.running and record.worker == worker  # by take_next
    if not taken and not store.start(job_id, worker, started):  # cancelled or deleted meanwhile
        return {"id": job_id, "state": "skipped", "error": None}
    try:
        outcome = _run(record, settings, store, started, celery_update)
    finally:  # the files are in the store: the copy goes before anyone is told the job ended
        store.storage.release(store.storage.work_folder(job_id))
    if outcome is None:
        return _hand_back(store, job_id, worker)
    state, error, detail = outcome
    return _finish(store, settings, record, state, error, detail=detail)


def _hand_back(store: JobStore, job_id: str, worker: str) -> dict[str, Any]:
    """The worker is stopping: the job goes back to the front of the queue, to resume from its
    last checkpoint on the next worker (the task sends its wake-up again)."""
    handed = store.hand_back(job_id, worker)
    log.warning("job %s: this worker is stopping; the job %s", job_id,
                "goes back to the queue" if handed else "changed meanwhile and is left as it is")
    return {"id": job_id, "state": HANDED_BACK if handed else "skipped", "error": None}


def _run(record: JobRecord, settings: Settings, store: JobStore, started: float,
         celery_update: Callable[[dict[str, Any]], None] | None) -> Outcome | None:
    """Fetch the job's files, run it, write everything back; the outcome, or None when the
    worker is stopping (the job was interrupted, its files written back)."""
    folder = store.storage.work_folder(record.id)
    scratch = Scratch(store.storage, record.id, folder, lambda: _gone(store, record.id))
    try:
        scratch.fetch()
    except OSError as exc:
        return _failure(exc, record, folder, settings)
    return _run_here(record, settings, store, started, celery_update, scratch)


def _run_here(record: JobRecord, settings: Settings, store: JobStore, started: float,
              celery_update: Callable[[dict[str, Any]], None] | None,
              scratch: Scratch) -> Outcome | None:
    from cadnerf_core.errors import JobCancelled
    from cadnerf_core.pipeline import run_job
    from cadnerf_core.progress import Progress

    device = device_kind(settings.device)
    work = record.work or _job_work(scratch.folder)
    eta = EtaModel(store.history.expected(record.preset, device, work))
    adapter = JobProgress(store, record.id, eta, celery_update=celery_update,
                          deadline=started + settings.job_soft_time_limit_s,
                          stopping=STOPPING.is_set)
    watchdog = _hard_limit_watchdog(store, record, settings.job_hard_time_limit_s)
    try:
        run_job(scratch.folder, get_library(str(settings.library_dir)),
                Progress(scratch.reporting(adapter), adapter.cancelled), settings.device,
                mask_model=settings.mask_model)
        scratch.write_back()  # every artifact is in the store before the job is done
    except JobCancelled:
        if adapter.interrupted:
            scratch.write_back(quiet=True)
            return None
        return _cancelled(adapter.timed_out, settings)
    except Exception as exc:
        scratch.write_back(quiet=True)  # the log and what was made, for the operator
        return _failure(exc, record, scratch.folder, settings)
    finally:
        watchdog.cancel()
    try:
        store.history.record(record.preset, device, unscaled(eta.finish(time.monotonic()), work))
    except redis.RedisError as exc:  # only the ETA of later jobs suffers
        log.warning("could not record stage times: %s", exc)
    return JobState.succeeded, None, None


def _gone(store: JobStore, job_id: str) -> bool:
    """Whether the job was cancelled or deleted (False while Redis cannot tell)."""
    try:
        return store.cancel_requested(job_id)
    except redis.RedisError:
        return False


def _cancelled(timed_out: bool, settings: Settings) -> Outcome:
    """A job stopped by a cancel, or by its soft time limit (then it failed)."""
    if timed_out:
        message = f"the job ran past its time limit of {settings.job_soft_time_limit_s} s"
        return JobState.failed, message, ErrorDetail(code="time_limit", message=message,
                                                     hint=TIME_LIMIT_HINT)
    return JobState.cancelled, None, None


def _failure(exc: Exception, record: JobRecord, folder: Path, settings: Settings) -> Outcome:
    """The failed outcome of an exception out of the pipeline, in words for the user."""
    from cadnerf_core.errors import CadNerfError, InputError, LibraryError

    if isinstance(exc, InputError):
        error, detail = input_error(str(exc), exc.item, exc.hint, record, folder)
        return JobState.failed, error, detail
    if isinstance(exc, LibraryError):
        return JobState.failed, str(exc), ErrorDetail(code="library_error", message=str(exc),
                                                      hint="the operator has to check the library")
    if isinstance(exc, CadNerfError):
        return JobState.failed, str(exc), ErrorDetail(code="job_failed", message=str(exc))
    if isinstance(exc, StorageError):
        log.error("job %s: the job store failed: %s", record.id, exc)
        message = "the job's storage could not be reached"
        return JobState.failed, f"{message}; submit the job again later", ErrorDetail(
            code="storage_error", message=message, hint="the operator has to check the object "
            "store; submit the job again later")
    if isinstance(exc, OSError):
        log.exception("job %s: storage error", record.id)
        return JobState.failed, _storage_message(exc, folder), _storage_detail(exc, folder)
    log.error("job %s failed", record.id, exc_info=exc)
    message = f"internal error ({type(exc).__name__})"
    return JobState.failed, f"{message}; see the worker log", ErrorDetail(
        code="internal", message=message, hint="the error was logged in the worker log")


def _job_work(folder: Path) -> dict[str, float]:
    """The work per stage of a job without one in its record (``app.state.stage_work``)."""
    try:
        return stage_work(JobFolder(folder).read_config())
    except (OSError, ValueError):  # the pipeline reports a broken config itself
        return {}


def uploaded_name(item: str, record: JobRecord) -> str | None:
    """The name a photo was uploaded under, from its stored name ``NNN_<name>`` (or a path to
    it); None when ``item`` names no stored photo of the job."""
    index = photo_index(item)
    if index is None or index >= len(record.names):
        return None
    return record.names[index]


def input_error(text: str, item: str | None, hint: str | None, record: JobRecord,
                folder: Path) -> tuple[str, ErrorDetail]:
    """The error string and the structured detail of a core ``InputError``.

    The photo is named as the user uploaded it (not by its stored name), an input of the job
    folder by its form field (``images``, ``masks``, ``config``), and no server path is shown.

    Args:
        text: ``str(exc)``: ``"<item>: <message> (<hint>)"``.
        item: ``exc.item``: a stored photo's name, a path, or a field.
        hint: ``exc.hint``.
        record: the job (its ``names`` are the uploaded photo names, in order).
        folder: the job folder.
    """
    message = text
    if item and message.startswith(f"{item}: "):
        message = message[len(item) + 2:]
    if hint and message.endswith(f" ({hint})"):
        message = message[:-len(hint) - 3]
    photo = field = label = None
    if item:
        photo = uploaded_name(item, record)
        label = photo or _job_relative(item, folder)
        if photo is None:
            field = UPLOAD_FIELDS.get(PurePath(label).parts[0]) if label else None
    detail = ErrorDetail(code="unusable_input", message=message, field=field, photo=photo,
                         hint=hint)
    error = f"{label}: {message}" if label else message
    return (f"{error} ({hint})" if hint else error), detail


def _job_relative(item: str, folder: Path) -> str:
    """``item`` as a path inside the job folder, or only its name when it is elsewhere."""
    path = PurePath(item)
    if not path.is_absolute():
        return item
    try:
        return str(path.relative_to(folder)) if path != PurePath(folder) else ""
    except ValueError:
        return path.name


def _storage_parts(exc: OSError, folder: Path) -> tuple[str, str, bool]:
    """(message, hint, disk full) when the job folder cannot be written (no server path)."""
    where = "the job folder"
    if exc.filename:
        try:
            where = f"`{Path(exc.filename).relative_to(folder)}` in the job folder"
        except ValueError:
            where = f"`{Path(exc.filename).name}` in the job folder"
    reason = exc.strerror or type(exc).__name__
    full = exc.errno in (errno.ENOSPC, errno.EDQUOT)
    hint = "the server's disk is full" if full else "check the storage of the job folders"
    return f"the job folder cannot be written: {reason} ({where})", hint, full


def _storage_message(exc: OSError, folder: Path) -> str:
    """What the user reads when the job folder cannot be written (no server path beyond it)."""
    message, hint, _ = _storage_parts(exc, folder)
    return f"{message}; {hint}"


def _storage_detail(exc: OSError, folder: Path) -> ErrorDetail:
    """``_storage_message`` as an error detail (``storage_full`` or ``storage_error``)."""
    message, hint, full = _storage_parts(exc, folder)
    return ErrorDetail(code="storage_full" if full else "storage_error", message=message,
                       hint=hint)


def _hard_limit_watchdog(store: JobStore, record: JobRecord, limit_s: float) -> threading.Timer:
    """Fail the job and end the process if a step hangs past the hard limit.

    The solo pool cannot interrupt a task; exiting is the only way to free the worker (the
    supervisor or the container restarts it; the re-delivered task sees a final state).
    """
    def expire() -> None:
        log.error("job %s passed the hard time limit (%s s); exiting", record.id, limit_s)
        message = f"the job passed the hard time limit of {limit_s:.0f} s"
        try:
            finish_job(store, record, JobState.failed, message,
                       ErrorDetail(code="time_limit", message=message, hint=TIME_LIMIT_HINT),
                       redis_wait_s=0.0)
        finally:
            os._exit(70)

    timer = threading.Timer(limit_s, expire)
    timer.daemon = True
    timer.start()
    return timer


def _finish(store: JobStore, settings: Settings, record: JobRecord, state: JobState,
            error: str | None, redis_wait_s: float = FINISH_RETRY_S,
            detail: ErrorDetail | None = None) -> dict[str, Any]:
    """Write the final state (``app.state.finish_job``), then call the job's webhook."""
    final, in_redis = finish_job(store, record, state, error, detail, redis_wait_s)
    log.info("job %s %s%s", record.id, state.value, f": {error}" if error else "")
    if record.webhook_url and (in_redis or store.read_state_file(record.id) is not None):
        payload = {"id": record.id, "state": state.value, "error": error,
                   "error_detail": (None if detail is None
                                    else detail.model_dump(mode="json", exclude_none=True)),
                   "finished_at": final.finished_at, "status_url": f"/v1/jobs/{record.id}",
                   "result_url": f"/v1/jobs/{record.id}/result"}
        send_webhook(record.webhook_url, payload, settings.webhook_secret,
                     allow_private=settings.webhook_allow_private)
    return {"id": record.id, "state": state.value, "error": error}
