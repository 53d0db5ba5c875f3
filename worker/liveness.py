"""The worker's heartbeat, the claim on the job it runs, and the start-up hunt for orphans.

One thread refreshes the worker's heartbeat (readiness) and, while a job runs, its claim (so no
other worker runs it at the same time). For the first seconds after start-up it also re-queues
jobs left ``running`` by a worker that died (``app.state.OrphanWatch``).

The heartbeat needs the interpreter: a native call that holds it (the GIL) past the claim's
lifetime lets the service take the running job for orphaned. The thread says so in the log when
a beat comes that late, and each beat re-arms ``faulthandler``'s watchdog (a thread of its own
that needs no interpreter): an interpreter held ``STALL_EXIT_S`` writes every thread's stack to
the log and ends the process, as the hard time limit does, so the supervisor starts a fresh
worker and recovery queues the job again, instead of a worker that beats no more and never
returns.
"""

from __future__ import annotations

import faulthandler
import logging
import os
import socket
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import redis

from app.settings import Settings
from app.state import HEARTBEAT_EVERY_S, HEARTBEAT_TTL_S, ORPHAN_GRACE_S, JobStore, OrphanWatch
from cadnerf_core.jobfolder import JobStorage
from worker.runner import device_kind

log = logging.getLogger(__name__)

STALL_EXIT_S = 300.0
"""An interpreter held this long (no heartbeat could run) ends the worker process."""


def worker_name() -> str:
    """This process's heartbeat name, ``<host>-<pid>``."""
    return f"{socket.gethostname()}-{os.getpid()}"


def _stderr_with_fd() -> Any:
    """The process's original stderr when it has a file descriptor (faulthandler writes to
    it without the interpreter), else None (then there is no stall watchdog)."""
    stream = sys.__stderr__
    try:
        stream.fileno()  # type: ignore[union-attr]
    except (AttributeError, OSError, ValueError):
        log.warning("no stall watchdog: the process has no stderr file to write stacks to")
        return None
    return stream


class Liveness:
    """Heartbeat and job claims of one worker process.

    Args:
        settings: deployment settings (Redis URL, data root).
        name: the heartbeat name recorded on the jobs this worker runs.
        send: queues a job id again (an orphan of a dead worker, a job handed back).
        startup_watch_s: how long after start-up to look for orphaned jobs.
        storage: where the job data lives (state.json of the jobs it recovers).
        stall_exit_s: how long the interpreter may be held before the process ends (None: never).
    """

    def __init__(self, settings: Settings, name: str, send: Callable[[str], Any],
                 startup_watch_s: float = 3 * ORPHAN_GRACE_S,
                 storage: JobStorage | None = None,
                 stall_exit_s: float | None = STALL_EXIT_S) -> None:
        self.store = JobStore.open(settings.redis_url, settings.data_root, storage)
        self.device_setting = settings.device
        self.name = name
        self.send = send
        self.startup_watch_s = startup_watch_s
        self.stall_exit_s = stall_exit_s
        # The process's own stderr: Celery swaps sys.stderr for a logger without a file.
        self._stall_file = _stderr_with_fd()
        self._job: str | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="heartbeat", daemon=True)
        self._last_error = ""

    def start(self) -> None:
        """Beat now and every ``HEARTBEAT_EVERY_S``; from now on a fatal signal (a native
        crash) writes every thread's stack to stderr before the process ends."""
        if self._stall_file is not None:
            faulthandler.enable(file=self._stall_file)
        self._thread.start()

    def hold(self, job_id: str) -> bool:
        """Claim a job for this worker; False when another live worker holds it."""
        if not self.store.claims.take(job_id, self.name):
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
            self.store.claims.release(job_id, self.name)
        except redis.RedisError as exc:  # it expires by itself
            log.warning("could not release the claim on job %s: %s", job_id, exc)

    def abandon(self) -> None:
        """The process must end now: hand the held job back to the queue and queue its
        wake-up again (best effort: else the job's claim lapses and recovery re-queues it)."""
        with self._lock:
            job = self._job
        try:
            if job is not None and self.store.hand_back(job, self.name):
                self.send(job)
                log.warning("job %s handed back to the queue", job)
        except Exception as exc:
            log.error("could not hand job %s back: %s", job, exc)
        self.stop()

    def _loop(self) -> None:
        # The device tells the API which preset to offer by default (app.state.serving);
        # resolving "auto" imports torch, so it happens here, after start-up, not at import.
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "device": device_kind(self.device_setting)}
        started = due = time.monotonic()
        watch = OrphanWatch(self.store, self.send)
        while not self._stop.is_set():
            try:
                self._note_stall(time.monotonic() - due)
                self._beat(info)
                if time.monotonic() - started < self.startup_watch_s:
                    watch.check()
                self._last_error = ""
            except Exception as exc:  # Redis away for a moment: keep trying
                if str(exc) != self._last_error:
                    log.warning("heartbeat failed: %s", exc)
                self._last_error = str(exc)
            due = time.monotonic() + HEARTBEAT_EVERY_S
            self._stop.wait(HEARTBEAT_EVERY_S)

    def _note_stall(self, late_s: float) -> None:
        """Re-arm the stall watchdog; log a beat late enough for the claim to lapse."""
        if self.stall_exit_s is not None and self._stall_file is not None:
            faulthandler.dump_traceback_later(self.stall_exit_s, exit=True, file=self._stall_file)
        if late_s > HEARTBEAT_TTL_S - HEARTBEAT_EVERY_S:
            with self._lock:
                job = self._job
            log.warning("the heartbeat came %.1f s late: a step held the interpreter%s", late_s,
                        f" (job {job} may have been taken for orphaned)" if job else "")

    def _beat(self, info: dict[str, Any]) -> None:
        self.store.workers.beat(self.name, info=info)
        with self._lock:
            job = self._job
        if job is not None:
            if not self.store.claims.take(job, self.name):
                log.error("job %s is claimed by %s while this worker runs it", job,
                          self.store.claims.holder(job))
            self.store.mark_running(job, True)

    def stop(self) -> None:
        """Stop beating and remove the key (readiness drops at once)."""
        self._stop.set()
        if self.stall_exit_s is not None and self._stall_file is not None:
            faulthandler.cancel_dump_traceback_later()
        try:
            self.store.workers.forget(self.name)
        except redis.RedisError as exc:
            log.debug("could not remove heartbeat: %s", exc)
