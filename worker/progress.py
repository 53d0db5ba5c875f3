"""Adapter from the core's progress protocol to the job store (Redis + state.json) and Celery.

The fraction done and the ETA come from ``app.state.EtaModel`` (expected seconds per stage by
preset and device, measured history, the observed rate of the running stage).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import redis

from app.state import EtaModel, JobStore

log = logging.getLogger(__name__)


class JobProgress:
    """Reporter and cancel check for one job, throttled so Redis sees a few writes a second.

    Redis going away does not stop the job: a failed write or cancel check is logged, skipped,
    and retried after ``retry_s`` (training goes on; the final state reaches state.json first).
    """

    def __init__(self, store: JobStore, job_id: str, eta: EtaModel, *,
                 deadline: float | None = None,
                 celery_update: Callable[[dict[str, Any]], None] | None = None,
                 throttle_s: float = 0.5, mirror_every_s: float = 5.0, retry_s: float = 2.0,
                 tick_s: float = 2.0, clock: Callable[[], float] = time.monotonic,
                 stopping: Callable[[], bool] | None = None) -> None:
        self.tick_s = tick_s
        self.stopping = stopping
        self.interrupted = False
        self.store = store
        self.job_id = job_id
        self.eta = eta
        self.deadline = deadline
        self.celery_update = celery_update
        self.throttle_s = throttle_s
        self.mirror_every_s = mirror_every_s
        self.retry_s = retry_s
        self.clock = clock
        self.timed_out = False
        self._last_write = -1e9
        self._last_mirror = clock()
        self._last_cancel_check = -1e9
        self._cancelled = False
        self._redis_down_until = -1e9
        self.redis_failures = 0

    def __call__(self, stage: str, done: int, total: int) -> None:
        """Record a finished step; write to Redis on a stage change or every ``throttle_s``."""
        now = self.clock()
        changed = stage != self.eta.stage
        fraction, eta_s = self.eta.update(stage, done, total, now)
        if not changed and now - self._last_write < self.throttle_s:
            return
        if now < self._redis_down_until:
            return
        self._write(now, stage, fraction, eta_s, changed, {"done": done, "total": total})

    def _write(self, now: float, stage: str, fraction: float, eta_s: float, changed: bool,
               extra: dict[str, Any]) -> None:
        self._last_write = now
        progress, eta = round(fraction, 4), round(eta_s, 1)
        try:
            self.store.update(self.job_id, stage=stage, progress=progress, eta_s=eta)
            if changed or now - self._last_mirror > self.mirror_every_s:
                self._last_mirror = now
                self.store.mirror(self.job_id)
        except redis.RedisError as exc:
            self._redis_failed(now, exc)
            return
        if self.celery_update is not None:
            try:
                self.celery_update({"stage": stage, "progress": progress, "eta_s": eta, **extra})
            except Exception as exc:  # the result backend is Redis too: same treatment
                self._redis_failed(now, exc)

    def _tick(self, now: float) -> None:
        """Move the ETA on between reports (``EtaModel.tick``), every ``tick_s``."""
        if self.eta.stage is None or now - self._last_write < self.tick_s \
                or now < self._redis_down_until:
            return
        moved = self.eta.tick(now)
        if moved is not None:
            self._write(now, self.eta.stage, moved[0], moved[1], False, {})

    def _redis_failed(self, now: float, exc: Exception) -> None:
        self.redis_failures += 1
        self._redis_down_until = now + self.retry_s
        log.warning("job %s: Redis unavailable (%s); training goes on, retrying in %.0f s",
                    self.job_id, exc, self.retry_s)

    def cancelled(self) -> bool:
        """True when the job was cancelled (Redis flag), ran past its soft time limit, or the
        worker is stopping (``interrupted``: the job goes back to the queue)."""
        if self.stopping is not None and self.stopping():
            self.interrupted = True
            return True
        now = self.clock()
        if self.deadline is not None and time.time() > self.deadline:
            self.timed_out = True
            return True
        if (not self._cancelled and now - self._last_cancel_check >= 0.25
                and now >= self._redis_down_until):
            self._last_cancel_check = now
            try:
                self._cancelled = self.store.cancel_requested(self.job_id)
            except redis.RedisError as exc:
                self._redis_failed(now, exc)
        if not self._cancelled:
            self._tick(now)  # the core checks on every step, and reports about once a second
        return self._cancelled
