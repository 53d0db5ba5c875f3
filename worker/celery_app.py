"""The worker's Celery app: the shared queue settings, a heartbeat, the library preloaded."""

from __future__ import annotations

import logging
import os
import socket
import threading
from typing import Any

from celery import Celery
from celery.signals import worker_ready, worker_shutdown

from app.queue import QUEUE, celery_config
from app.settings import Settings
from app.store import beat, connect, heartbeat_key

log = logging.getLogger(__name__)

HEARTBEAT_EVERY_S = 5.0
HEARTBEAT_TTL_S = 15.0


class Heartbeat:
    """Refreshes ``cadnerf:worker:<name>`` in Redis from a thread while the worker lives."""

    def __init__(self, settings: Settings, name: str) -> None:
        self.client = connect(settings.redis_url)
        self.name = name
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="heartbeat", daemon=True)

    def start(self) -> None:
        """Beat now and every few seconds."""
        self._thread.start()

    def _loop(self) -> None:
        info = {"pid": os.getpid(), "host": socket.gethostname()}
        while not self._stop.is_set():
            try:
                beat(self.client, self.name, HEARTBEAT_TTL_S, info)
            except Exception as exc:  # Redis away for a moment: keep trying
                log.warning("heartbeat failed: %s", exc)
            self._stop.wait(HEARTBEAT_EVERY_S)

    def stop(self) -> None:
        """Stop beating and remove the key (readiness drops at once)."""
        self._stop.set()
        try:
            self.client.delete(heartbeat_key(self.name))
        except Exception as exc:
            log.debug("could not remove heartbeat: %s", exc)


def create_celery(settings: Settings) -> Celery:
    """The worker's Celery app, configured like the API's producer.

    Args:
        settings: deployment settings.

    Returns:
        A Celery app with the ``cadnerf.run_job`` task registered.
    """
    celery = Celery("cadnerf", include=["worker.tasks"])
    celery.conf.update(celery_config(settings))
    celery.conf.update(worker_concurrency=1, task_queues=None, task_create_missing_queues=True)
    celery.conf.cadnerf_settings = settings
    _connect_signals(celery, settings)
    return celery


def _connect_signals(celery: Celery, settings: Settings) -> None:
    name = f"{socket.gethostname()}-{os.getpid()}"
    heartbeat = Heartbeat(settings, name)

    @worker_ready.connect(weak=False)
    def _ready(**_: Any) -> None:
        _preload_library(settings)
        heartbeat.start()
        log.info("worker %s ready on queue %s", name, QUEUE)

    @worker_shutdown.connect(weak=False)
    def _shutdown(**_: Any) -> None:
        heartbeat.stop()


def _preload_library(settings: Settings) -> None:
    """Load the library before the first job (and log clearly when it is missing)."""
    from worker.runner import get_library

    try:
        get_library(str(settings.library_dir))
    except Exception as exc:  # jobs will fail with the library's own message
        log.error("the CAD library at %s cannot be loaded: %s", settings.library_dir, exc)
