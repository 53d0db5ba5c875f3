"""Sending a job to the workers by task name (the API never imports the worker package: it
would pull in the core and torch). The queue settings are shared through ``app.state``."""

from __future__ import annotations

from celery import Celery

from app.settings import Settings
from app.state import QUEUE, SEND_RETRY_POLICY, TASK_NAME, celery_config


def make_producer(settings: Settings) -> Celery:
    """A Celery app used only to send tasks."""
    producer = Celery("cadnerf-api", set_as_current=False)
    producer.conf.update(celery_config(settings))
    return producer


def enqueue(producer: Celery, job_id: str) -> None:
    """Queue a job for the workers (bounded retries so a dead broker fails fast)."""
    producer.send_task(TASK_NAME, args=[job_id], queue=QUEUE, retry=True,
                       retry_policy=SEND_RETRY_POLICY)
