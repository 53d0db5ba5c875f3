"""What the task does with a job id: state transitions around one call of the core pipeline."""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.schemas import JobState
from app.settings import Settings
from app.store import JobRecord, JobStore
from worker.progress import EtaModel, JobProgress, expected_stage_seconds, record_stage_seconds
from worker.webhook import send_webhook

if TYPE_CHECKING:
    from cadnerf_core.library import Library

log = logging.getLogger(__name__)


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


def execute(job_id: str, settings: Settings, store: JobStore,
            celery_update: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Run one job to a final state.

    Args:
        job_id: the job (its folder is ``settings.data_root / job_id``).
        settings: deployment settings (library, device, time limits, webhook secret).
        store: job state.
        celery_update: receives progress fields for Celery's custom state.

    Returns:
        ``{"id", "state", "error"}`` (a JSON-serialisable summary).
    """
    record = store.get(job_id)
    if record is None or record.state.terminal:
        state = "missing" if record is None else record.state.value
        log.info("job %s: nothing to do (%s)", job_id, state)
        return {"id": job_id, "state": state, "error": None}
    if store.cancel_requested(job_id):
        return _finish(store, settings, record, JobState.cancelled, None)
    started = record.started_at or time.time()
    if not store.update(job_id, allowed_from=(JobState.queued, JobState.running),
                        state=JobState.running, started_at=started, error=None):
        return {"id": job_id, "state": "skipped", "error": None}
    store.mirror(job_id)
    state, error = _run(record, settings, store, started, celery_update)
    return _finish(store, settings, record, state, error)


def _run(record: JobRecord, settings: Settings, store: JobStore, started: float,
         celery_update: Callable[[dict[str, Any]], None] | None) -> tuple[JobState, str | None]:
    from cadnerf_core.pipeline import run_job

    from cadnerf_core.errors import CadNerfError, InputError, JobCancelled, LibraryError
    from cadnerf_core.progress import Progress

    device = device_kind(settings.device)
    eta = EtaModel(expected_stage_seconds(store.r, record.preset, device))
    adapter = JobProgress(store, record.id, eta, celery_update=celery_update,
                          deadline=started + settings.job_soft_time_limit_s)
    watchdog = _hard_limit_watchdog(store, record.id, settings.job_hard_time_limit_s)
    try:
        run_job(store.job_dir(record.id), get_library(str(settings.library_dir)),
                Progress(adapter, adapter.cancelled), settings.device)
    except JobCancelled:
        if adapter.timed_out:
            return JobState.failed, (f"the job ran past its time limit of "
                                     f"{settings.job_soft_time_limit_s} s")
        return JobState.cancelled, None
    except (InputError, LibraryError, CadNerfError) as exc:
        return JobState.failed, str(exc)
    except Exception as exc:
        log.exception("job %s failed", record.id)
        return JobState.failed, f"internal error ({type(exc).__name__}); see the worker log"
    finally:
        watchdog.cancel()
    if eta.stage is not None:
        eta.durations[eta.stage] = time.monotonic() - eta.stage_started
    record_stage_seconds(store.r, record.preset, device, eta.durations)
    return JobState.succeeded, None


def _hard_limit_watchdog(store: JobStore, job_id: str, limit_s: float) -> threading.Timer:
    """Fail the job and end the process if a step hangs past the hard limit.

    The solo pool cannot interrupt a task; exiting is the only way to free the worker (the
    supervisor or the container restarts it; the re-delivered task sees a final state).
    """
    def expire() -> None:
        log.error("job %s passed the hard time limit (%s s); exiting", job_id, limit_s)
        store.update(job_id, state=JobState.failed, finished_at=time.time(),
                     error=f"the job passed the hard time limit of {limit_s:.0f} s")
        store.mirror(job_id)
        os._exit(70)

    timer = threading.Timer(limit_s, expire)
    timer.daemon = True
    timer.start()
    return timer


def _finish(store: JobStore, settings: Settings, record: JobRecord, state: JobState,
            error: str | None) -> dict[str, Any]:
    fields: dict[str, Any] = {"state": state, "finished_at": time.time(), "error": error}
    if state == JobState.succeeded:
        fields.update(progress=1.0, eta_s=0.0)
    else:
        fields.update(eta_s=None)
    store.update(record.id, **fields)
    store.mirror(record.id)
    log.info("job %s %s%s", record.id, state.value, f": {error}" if error else "")
    if record.webhook_url and store.r.exists(store.job_key(record.id)):
        payload = {"id": record.id, "state": state.value, "error": error,
                   "finished_at": fields["finished_at"], "status_url": f"/v1/jobs/{record.id}",
                   "result_url": f"/v1/jobs/{record.id}/result"}
        send_webhook(record.webhook_url, payload, settings.webhook_secret)
    return {"id": record.id, "state": state.value, "error": error}
