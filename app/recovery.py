"""Jobs whose worker died: per-job claims, the set of running jobs, and re-queueing orphans.

A worker claims a job before running it (``cadnerf:claim:<id>`` = its heartbeat name, a short
TTL its heartbeat refreshes), so a duplicate delivery never runs a job twice at once. A job in
state ``running`` whose claim has expired (its worker stopped beating) is an orphan:
it is put back to ``queued`` and sent again (the pipeline resumes from its checkpoints), at most
``MAX_ATTEMPTS`` times in all. Used by the API (its recovery loop) and the worker (at start-up);
imports neither FastAPI nor Celery's worker side.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import redis

from app.schemas import JobState
from app.store import PREFIX, RUNNING_KEY, JobRecord, JobStore

log = logging.getLogger(__name__)

HEARTBEAT_TTL_S = 5.0  # a killed worker disappears from /readyz and its claims lapse after this
HEARTBEAT_EVERY_S = 1.5
ORPHAN_GRACE_S = HEARTBEAT_TTL_S  # seen orphaned this long before re-queueing (Redis restarts)
MAX_ATTEMPTS = 3  # runs of one job in all (the first one included)

# Take or refresh a claim: only when free or already ours.
_CLAIM_LUA = """
local holder = redis.call('get', KEYS[1])
if holder and holder ~= ARGV[1] then return 0 end
redis.call('set', KEYS[1], ARGV[1], 'PX', ARGV[2])
return 1
"""
_RELEASE_LUA = """
if redis.call('get', KEYS[1]) == ARGV[1] then return redis.call('del', KEYS[1]) end
return 0
"""
# Running -> queued (or failed past the attempt bound), only while still held by the dead worker.
_REQUEUE_LUA = """
if redis.call('hget', KEYS[1], 'state') ~= 'running' then return -1 end
if (redis.call('hget', KEYS[1], 'worker') or '') ~= ARGV[1] then return -1 end
if redis.call('exists', KEYS[2]) == 1 then return -1 end
local attempts = tonumber(redis.call('hget', KEYS[1], 'attempts') or '0') or 0
attempts = attempts + 1
if attempts >= tonumber(ARGV[2]) then
  redis.call('hset', KEYS[1], 'state', 'failed', 'attempts', attempts, 'worker', '',
             'finished_at', ARGV[3], 'updated_at', ARGV[3], 'eta_s', '', 'error', ARGV[4])
  return 0
end
redis.call('hset', KEYS[1], 'state', 'queued', 'attempts', attempts, 'worker', '',
           'updated_at', ARGV[3], 'eta_s', '')
return attempts
"""


def claim_key(job_id: str) -> str:
    """Who runs the job right now (expires unless its worker's heartbeat refreshes it)."""
    return f"{PREFIX}:claim:{job_id}"


def claim(client: redis.Redis, job_id: str, worker: str,
          ttl_s: float = HEARTBEAT_TTL_S) -> bool:
    """Take (or refresh) the claim on a job; False when another worker holds it."""
    ttl_ms = str(max(1, int(ttl_s * 1000)))
    return bool(client.eval(_CLAIM_LUA, 1, claim_key(job_id), worker, ttl_ms))


def claim_holder(client: redis.Redis, job_id: str) -> str | None:
    """The worker holding the job's claim, or None."""
    holder = client.get(claim_key(job_id))
    return None if holder is None else str(holder)


def release(client: redis.Redis, job_id: str, worker: str) -> None:
    """Give up our claim (someone else's is left alone)."""
    client.eval(_RELEASE_LUA, 1, claim_key(job_id), worker)


def mark_running(client: redis.Redis, job_id: str, running: bool) -> None:
    """Add the job to (or remove it from) the set of running jobs the recovery scans."""
    if running:
        client.sadd(RUNNING_KEY, job_id)
    else:
        client.srem(RUNNING_KEY, job_id)


def find_orphans(store: JobStore) -> list[JobRecord]:
    """Jobs in state ``running`` that no worker claims.

    The claim is the per-job heartbeat: the worker's heartbeat thread refreshes it with its own
    key, so it lapses ``HEARTBEAT_TTL_S`` after the worker dies (a restarted worker that got the
    same ``<host>-<pid>`` name, as in a container, does not hide the job). A job whose
    state.json is already final (Redis missed the last write) is re-seeded, not re-queued.

    Args:
        store: job state.

    Returns:
        The orphaned records (the running set is pruned of jobs that are no longer running).
    """
    ids = sorted(str(i) for i in store.r.smembers(RUNNING_KEY))  # type: ignore[union-attr]
    if not ids:
        return []
    orphans = []
    for job_id in ids:
        record = store.get(job_id)
        if record is None or record.state != JobState.running:
            mark_running(store.r, job_id, False)
            continue
        if claim_holder(store.r, job_id):
            continue
        on_disk = store.read_state_file(job_id)
        if on_disk is not None and on_disk.state.terminal:  # Redis missed the final write
            store.reseed(on_disk)
            mark_running(store.r, job_id, False)
            continue
        orphans.append(record)
    return orphans


def requeue(store: JobStore, record: JobRecord, send: Callable[[str], Any],
            max_attempts: int = MAX_ATTEMPTS) -> str:
    """Put an orphaned job back in the queue, or fail it once it has used its attempts.

    Args:
        store: job state.
        record: the orphan as ``find_orphans`` saw it.
        send: queues a job id (``enqueue`` with a producer, or a Celery app's ``send_task``).
        max_attempts: runs allowed in all.

    Returns:
        "queued", "failed", or "skipped" when the job changed meanwhile (another process
        re-queued it, or its worker came back).
    """
    now = f"{time.time():.6f}"
    error = (f"the job's worker stopped {max_attempts} times while running it; "
             "not retried again (see the worker logs)")
    outcome = int(store.r.eval(_REQUEUE_LUA, 2, store.job_key(record.id),  # type: ignore[arg-type]
                               claim_key(record.id), record.worker or "", str(max_attempts),
                               now, error))
    if outcome < 0:
        return "skipped"
    mark_running(store.r, record.id, False)
    store.mirror(record.id)
    if outcome == 0:
        log.error("job %s: %s", record.id, error)
        return "failed"
    log.warning("job %s: worker %s is gone; queued again (attempt %d of %d)", record.id,
                record.worker or "?", outcome + 1, max_attempts)
    store.join_queue(record.id)
    try:
        send(record.id)
    except Exception as exc:  # a queued job without a message would wait for ever
        log.error("job %s could not be queued again: %s", record.id, exc)
        store.update(record.id, allowed_from=(JobState.queued,), state=JobState.failed,
                     finished_at=time.time(), error="the job's worker stopped and the job could "
                     "not be queued again; submit it again")
        store.mirror(record.id)
        return "failed"
    return "queued"


class OrphanWatch:
    """Re-queues jobs seen orphaned on two checks at least ``grace_s`` apart.

    The grace covers a Redis restart: heartbeats and claims come back within one heartbeat
    period, and a job must not be handed to a second worker in that window.
    """

    def __init__(self, store: JobStore, send: Callable[[str], Any],
                 grace_s: float = ORPHAN_GRACE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.store = store
        self.send = send
        self.grace_s = grace_s
        self.clock = clock
        self._first_seen: dict[tuple[str, str], float] = {}

    def check(self) -> list[str]:
        """One pass; returns the ids re-queued (or failed) in it."""
        now = self.clock()
        orphans = {(r.id, r.worker or ""): r for r in find_orphans(self.store)}
        self._first_seen = {k: self._first_seen.get(k, now) for k in orphans}
        handled = []
        for key, record in orphans.items():
            if now - self._first_seen[key] >= self.grace_s:
                if requeue(self.store, record, self.send) != "skipped":
                    handled.append(record.id)
                self._first_seen.pop(key, None)
        return handled
