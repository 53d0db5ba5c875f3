"""The one task: ``cadnerf.run_job(job_id)``. Messaging only; the work is in ``worker.runner``."""

from __future__ import annotations

from typing import Any

from celery import Task, shared_task

from app.settings import Settings
from app.state import JobStore
from worker import runner

PROGRESS_STATE = "PROGRESS"
DEFER_S = 5  # a deferred wake-up comes back after this (a running job of its owner may end)


@shared_task(name="cadnerf.run_job", bind=True, acks_late=True, reject_on_worker_lost=True,
             ignore_result=False)
def run_job(self: Task, job_id: str) -> dict[str, Any]:
    """Run the job whose folder is ``<data root>/<job_id>``; returns its final state."""
    settings: Settings = self.app.conf.cadnerf_settings
    store = JobStore.open(settings.redis_url, settings.data_root,
                          getattr(self.app.conf, "cadnerf_storage", None))

    def celery_update(meta: dict[str, Any]) -> None:
        self.update_state(state=PROGRESS_STATE, meta=meta)

    liveness = getattr(self.app.conf, "cadnerf_liveness", None)
    try:
        outcome = runner.execute(job_id, settings, store, celery_update, liveness)
    finally:
        store.close()
    if outcome["state"] == runner.DEFERRED:  # keep the wake-up: a queued job still needs it
        raise self.retry(countdown=DEFER_S, max_retries=None)
    if outcome["state"] == runner.HANDED_BACK:  # this worker stops: the next one takes the job
        raise self.retry(countdown=0, max_retries=None)
    return outcome
