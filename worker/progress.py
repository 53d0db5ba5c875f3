"""Adapter from the core's progress protocol to the job store (Redis + state.json) and Celery.

The fraction done weights each stage by its expected duration; the ETA starts from a per-preset
table of expected seconds per stage, is replaced by the durations workers measured for earlier
jobs (kept in Redis per preset and device), and is refined by the observed rate of the stage
being run. The default table and the measured-times keys live in ``app.store``: the API
estimates the wait of queued jobs from them too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import redis

from app.store import DEFAULT_STAGE_SECONDS, JobStore, stage_table, stage_times_key

log = logging.getLogger(__name__)

STAGES = ("masks", "retrieval", "phase1", "phase2", "phase3", "render", "export")
MEASURED_WEIGHT = 0.5  # exponential moving average of measured stage durations

__all__ = ["DEFAULT_STAGE_SECONDS", "MEASURED_WEIGHT", "STAGES", "EtaModel", "JobProgress",
           "expected_stage_seconds", "record_stage_seconds", "stage_times_key"]


def expected_stage_seconds(client: redis.Redis, preset: str, device: str) -> dict[str, float]:
    """Expected seconds per stage: measured values where known, else the default table."""
    try:
        measured = client.hgetall(stage_times_key(preset, device))
    except redis.RedisError:
        measured = {}
    return stage_table(preset, measured)  # type: ignore[arg-type]


def record_stage_seconds(client: redis.Redis, preset: str, device: str,
                         durations: Mapping[str, float]) -> None:
    """Fold one job's measured stage durations into the per-preset averages."""
    key = stage_times_key(preset, device)
    old = client.hgetall(key)
    new = {}
    for stage, seconds in durations.items():
        previous = old.get(stage)  # type: ignore[union-attr]
        new[stage] = (seconds if previous is None
                      else MEASURED_WEIGHT * seconds + (1 - MEASURED_WEIGHT) * float(previous))
    if new:
        client.hset(key, mapping={k: f"{v:.4f}" for k, v in new.items()})


@dataclass
class EtaModel:
    """Fraction done and seconds left from stage reports."""

    expected: dict[str, float]
    stage: str | None = None
    stage_started: float = 0.0
    durations: dict[str, float] = field(default_factory=dict)
    fraction: float = 0.0

    def update(self, stage: str, done: int, total: int, now: float) -> tuple[float, float]:
        """Account for a report; returns (fraction done in [0, 1], seconds left)."""
        if stage != self.stage:
            if self.stage is not None:
                self.durations[self.stage] = now - self.stage_started
            self.stage, self.stage_started = stage, now
        part = min(max(done / total, 0.0), 1.0) if total > 0 else 0.0
        order = list(STAGES) if stage in STAGES else [*STAGES, stage]
        position = order.index(stage)
        weights = [self.expected.get(s, 1.0) for s in order]
        done_weight = sum(weights[:position]) + weights[position] * part
        self.fraction = max(self.fraction, min(done_weight / sum(weights), 1.0))
        return self.fraction, self._eta(order, position, part, now)

    def _eta(self, order: list[str], position: int, part: float, now: float) -> float:
        measured = [(self.durations[s], self.expected.get(s, 1.0)) for s in order[:position]
                    if s in self.durations]
        # The finished stages tell how fast this machine is against the table: the current
        # stage's planned time is scaled by that before its own rate is known.
        expected_now = self.expected.get(order[position], 1.0) * _speed(measured)
        elapsed = now - self.stage_started
        observed_total = elapsed / part if part > 0 and elapsed > 0.2 else None
        # The observed rate of this stage is trusted more as the stage advances.
        if observed_total is None:
            current_left = expected_now * (1 - part)
        else:
            current_left = (part * observed_total * (1 - part)
                            + (1 - part) * expected_now * (1 - part))
            measured.append((observed_total, self.expected.get(order[position], 1.0)))
        future = sum(self.expected.get(s, 1.0) for s in order[position + 1:]) * _speed(measured)
        return max(current_left + future, 0.0)


def _speed(measured: list[tuple[float, float]]) -> float:
    """Measured over planned seconds of (measured, planned) pairs (1 without any), bounded."""
    spent = sum(m for m, _ in measured)
    planned = sum(e for _, e in measured)
    return min(max(spent / planned, 0.05), 50.0) if planned > 0 and spent > 0 else 1.0


class JobProgress:
    """Reporter and cancel check for one job, throttled so Redis sees a few writes a second.

    Redis going away does not stop the job: a failed write or cancel check is logged, skipped,
    and retried after ``retry_s`` (training goes on; the final state reaches state.json first).
    """

    def __init__(self, store: JobStore, job_id: str, eta: EtaModel, *,
                 deadline: float | None = None,
                 celery_update: Callable[[dict[str, Any]], None] | None = None,
                 throttle_s: float = 0.5, mirror_every_s: float = 5.0, retry_s: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
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
                self.celery_update({"stage": stage, "progress": progress, "eta_s": eta,
                                    "done": done, "total": total})
            except Exception as exc:  # the result backend is Redis too: same treatment
                self._redis_failed(now, exc)

    def _redis_failed(self, now: float, exc: Exception) -> None:
        self.redis_failures += 1
        self._redis_down_until = now + self.retry_s
        log.warning("job %s: Redis unavailable (%s); training goes on, retrying in %.0f s",
                    self.job_id, exc, self.retry_s)

    def cancelled(self) -> bool:
        """True when the job was cancelled (Redis flag) or ran past its soft time limit."""
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
        return self._cancelled
