"""The queue's settings, shared by the API (which sends a job by task name) and the worker.

Plain data, so that neither side imports the other (and this package imports no Celery).
"""

from __future__ import annotations

from typing import Any

from app.settings import Settings

TASK_NAME = "cadnerf.run_job"
QUEUE = "cadnerf"
# Sending a job retries briefly, so that a dead broker fails the request (or the re-queue) fast.
SEND_RETRY_POLICY = {"max_retries": 2, "interval_start": 0.2, "interval_step": 0.5,
                     "interval_max": 1.0}


def celery_config(settings: Settings) -> dict[str, Any]:
    """Queue settings shared by the API (producer) and the worker (consumer).

    Args:
        settings: deployment settings (broker URL, time limits).

    Returns:
        A mapping for ``Celery.conf.update``.
    """
    # The broker re-delivers an unacknowledged task after the visibility timeout: it must be
    # longer than any job, or a long job would run twice.
    visibility = settings.job_hard_time_limit_s + 600
    return {
        "broker_url": settings.redis_url,
        "result_backend": settings.redis_url,
        "task_serializer": "json",
        "result_serializer": "json",
        "accept_content": ["json"],
        "result_accept_content": ["json"],
        "task_default_queue": QUEUE,
        "task_acks_late": True,
        "task_reject_on_worker_lost": True,
        "worker_prefetch_multiplier": 1,
        "task_soft_time_limit": settings.job_soft_time_limit_s,
        "task_time_limit": settings.job_hard_time_limit_s,
        "result_expires": 24 * 3600,
        "broker_transport_options": {"visibility_timeout": visibility},
        # Progress goes to the result backend too: fail fast when Redis is away (the job goes
        # on; the job store has the state), instead of Celery's default 20 retries.
        "result_backend_transport_options": {
            "visibility_timeout": visibility,
            "retry_policy": {"max_retries": 1, "interval_start": 0, "interval_step": 0.5,
                             "interval_max": 0.5}},
        "broker_connection_retry_on_startup": True,
        "worker_hijack_root_logger": False,
        "task_track_started": True,
        "enable_utc": True,
    }
