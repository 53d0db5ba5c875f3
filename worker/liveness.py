"""The worker's heartbeat, the claim on the job it runs, and the start-up hunt for orphans.

One thread refreshes ``cadnerf:worker:<name>`` (readiness) and, while a job runs, its claim
``cadnerf:claim:<id>`` (so no other worker runs it at the same time). For the first seconds after
start-up it also re-queues jobs left ``running`` by a worker that died (``app.recovery``).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from typing import Any

import redis

from app import recovery
from app.queue import enqueue, make_producer
from app.settings import Settings
from app.store import JobStore, beat, connect, forget_worker

log = logging.getLogger(__name__)


def worker_name() -> str:
    """This process's heartbeat name, ``<host>-<pid>``."""
    return f"{socket.gethostname()}-{os.getpid()}"


class Liveness:
    """Heartbeat and job claims of one worker process.

    Args:
        settings: deployment settings (Redis URL, data root).
        name: the heartbeat name recorded on the jobs this worker runs.
        startup_watch_s: how long after start-up to look for orphaned jobs.
    """

    def __init__(self, settings: Settings, name: str,
                 startup_watch_s: float = 3 * recovery.ORPHAN_GRACE_S) -> None:
        self.settings = settings
        self.client = connect(settings.redis_url)
        self.name = name
        self.startup_watch_s = startup_watch_s
        self._job: str | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="heartbeat", daemon=True)
        self._last_error = ""

    def start(self) -> None:
        """Beat now and every ``HEARTBEAT_EVERY_S``."""
        self._thread.start()

    def hold(self, job_id: str) -> bool:
        """Claim a job for this worker; False when another live worker holds it."""
        if not recovery.claim(self.client, job_id, self.name):
            return False
        with self._lock:
            self._job = job_id
        return True

    def drop(self, job_id: str) -> None:
        """Release the claim once the job has reached a final state (best effort)."""
        with self._lock:
            if self._job == job_id:
                self._job = None
        try:
            recovery.release(self.client, job_id, self.name)
        except redis.RedisError as exc:  # it expires by itself
            log.warning("could not release the claim on job %s: %s", job_id, exc)

    def _loop(self) -> None:
        info = {"pid": os.getpid(), "host": socket.gethostname()}
        started = time.monotonic()
        watch = recovery.OrphanWatch(JobStore(self.client, self.settings.data_root), self._send)
        while not self._stop.is_set():
            try:
                self._beat(info)
                if time.monotonic() - started < self.startup_watch_s:
                    watch.check()
                self._last_error = ""
            except Exception as exc:  # Redis away for a moment: keep trying
                if str(exc) != self._last_error:
                    log.warning("heartbeat failed: %s", exc)
                self._last_error = str(exc)
            self._stop.wait(recovery.HEARTBEAT_EVERY_S)

    def _beat(self, info: dict[str, Any]) -> None:
        beat(self.client, self.name, recovery.HEARTBEAT_TTL_S, info)
        with self._lock:
            job = self._job
        if job is not None:
            if not recovery.claim(self.client, job, self.name):
                log.error("job %s is claimed by %s while this worker runs it", job,
                          recovery.claim_holder(self.client, job))
            recovery.mark_running(self.client, job, True)

    def _send(self, job_id: str) -> None:
        producer = make_producer(self.settings)
        try:
            enqueue(producer, job_id)
        finally:
            producer.close()

    def stop(self) -> None:
        """Stop beating and remove the key (readiness drops at once)."""
        self._stop.set()
        try:
            forget_worker(self.client, self.name)
        except redis.RedisError as exc:
            log.debug("could not remove heartbeat: %s", exc)
