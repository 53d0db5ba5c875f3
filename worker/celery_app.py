"""The worker's Celery app: the shared queue settings, liveness (heartbeat, claims), the library
preloaded."""

from __future__ import annotations

import logging
from typing import Any

from celery import Celery
from celery.signals import worker_ready, worker_shutdown, worker_shutting_down

from app.settings import Settings
from app.state import QUEUE, SEND_RETRY_POLICY, TASK_NAME, celery_config, open_checked_storage
from worker.liveness import Liveness, worker_name
from worker.shutdown import end_process, reclaim_stop_signals, request_stop

log = logging.getLogger(__name__)


def create_celery(settings: Settings) -> Celery:
    """The worker's Celery app, configured like the API's producer.

    Args:
        settings: deployment settings.

    Returns:
        A Celery app with the ``cadnerf.run_job`` task registered.

    Raises:
        StorageError: the job store cannot be used (checked here, before any job is taken).
    """
    celery = Celery("cadnerf", include=["worker.tasks"])
    celery.conf.update(celery_config(settings))
    celery.conf.update(worker_concurrency=1, task_queues=None, task_create_missing_queues=True)
    celery.conf.cadnerf_settings = settings
    celery.conf.cadnerf_storage = open_checked_storage(settings)
    _connect_signals(celery, settings)
    return celery


def _connect_signals(celery: Celery, settings: Settings) -> None:
    name = worker_name()

    def send(job_id: str) -> None:  # re-queues a dead worker's job through this app
        celery.send_task(TASK_NAME, args=[job_id], queue=QUEUE, retry=True,
                         retry_policy=SEND_RETRY_POLICY)

    liveness = Liveness(settings, name, send, storage=celery.conf.cadnerf_storage)
    celery.conf.cadnerf_liveness = liveness  # the task claims its jobs through it

    @worker_ready.connect(weak=False)
    def _ready(**_: Any) -> None:
        _preload_library(settings)
        reclaim_stop_signals()
        liveness.start()  # heartbeat, claims, and re-queueing jobs of dead workers
        log.info("worker %s ready on queue %s", name, QUEUE)

    @worker_shutting_down.connect(weak=False)
    def _stopping(**_: Any) -> None:  # SIGTERM or SIGINT: the running job goes back in time
        request_stop(liveness)

    @worker_shutdown.connect(weak=False)
    def _shutdown(**_: Any) -> None:
        liveness.stop()
        end_process()  # Celery is done: the interpreter's own teardown would take seconds


def _preload_library(settings: Settings) -> None:
    """Load the library before the first job (and log clearly when it is missing)."""
    from worker.runner import get_library

    try:
        get_library(str(settings.library_dir))
    except Exception as exc:  # jobs will fail with the library's own message
        log.error("the CAD library at %s cannot be loaded: %s", settings.library_dir, exc)
