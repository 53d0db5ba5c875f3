"""Jobs whose worker died: finding orphans and putting them back in the queue.

A job in state ``running`` whose claim has lapsed (its worker stopped beating) is an orphan:
it is put back to ``queued`` and sent again (the pipeline resumes from its checkpoints), at
most ``MAX_ATTEMPTS`` runs in all. The API's recovery loop and each worker at start-up look.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from app.state.claims import HEARTBEAT_TTL_S
from app.state.records import JobRecord, JobState
from app.state.store import JobStore

log = logging.getLogger(__name__)

ORPHAN_GRACE_S = HEARTBEAT_TTL_S  # seen orphaned this long before re-queueing (Redis restarts)
MAX_ATTEMPTS = 3  # runs of one job in all (the first one included)
STALL_S = 30.0  # the same job first in the queue this long while a worker is idle: wake one


def find_orphans(store: JobStore) -> list[JobRecord]:
    """Jobs in state ``running`` that no worker claims.

    The claim lapses ``HEARTBEAT_TTL_S`` after the worker dies (a restarted worker that got
    the same ``<host>-<pid>`` name, as in a container, does not hide the job). A job whose
    state.json is already final (Redis missed the last write) is re-seeded, not re-queued.
    The running set is pruned of jobs that are no longer running.
    """
    orphans = []
    for job_id in store.running_ids():
        record = store.get(job_id)
        if record is None or record.state != JobState.running:
            store.mark_running(job_id, False)
            continue
        if store.claims.holder(job_id):
            continue
        on_disk = store.read_state_file(job_id)
        if on_disk is not None and on_disk.state.terminal:  # Redis missed the final write
            store.reseed(on_disk)
            store.mark_running(job_id, False)
            continue
        orphans.append(record)
    return orphans


def requeue(store: JobStore, record: JobRecord, send: Callable[[str], Any],
            max_attempts: int = MAX_ATTEMPTS) -> str:
    """Put an orphaned job back in the queue, or fail it once it has used its attempts.

    Args:
        store: job state.
        record: the orphan as ``find_orphans`` saw it.
        send: queues a job id for the workers (the API's producer, a worker's Celery app).
        max_attempts: runs allowed in all.

    Returns:
        "queued", "failed", or "skipped" when the job changed meanwhile (another process
        re-queued it, or its worker came back).
    """
    error = (f"the job's worker stopped {max_attempts} times while running it; "
             "not retried again (see the worker logs)")
    outcome = store.requeue_orphan(record, max_attempts, error)
    if outcome < 0:
        return "skipped"
    if outcome == 0:
        log.error("job %s: %s", record.id, error)
        return "failed"
    log.warning("job %s: worker %s is gone; queued again (attempt %d of %d)", record.id,
                record.worker or "?", outcome + 1, max_attempts)
    try:
        send(record.id)
    except Exception as exc:  # a queued job without a message would wait for ever
        log.error("job %s could not be queued again: %s", record.id, exc)
        store.update(record.id, allowed_from=(JobState.queued,), state=JobState.failed,
                     finished_at=time.time(), error="the job's worker stopped and the job could "
                     "not be queued again; submit it again")
        store.leave_queue(record.id)
        store.mirror(record.id)
        return "failed"
    return "queued"


class OrphanWatch:
    """Re-queues jobs seen orphaned on two checks at least ``grace_s`` apart, and wakes idle
    workers when the queue stalls.

    The grace covers a Redis restart: heartbeats and claims come back within one heartbeat
    period, and a job must not be handed to a second worker in that window. A queue stalls
    when the broker lost its messages (a Redis restarted empty: the jobs come back from their
    state.json, their wake-ups do not); a message only wakes a worker, which takes the next
    job in fair order, so an extra one is harmless.
    """

    def __init__(self, store: JobStore, send: Callable[[str], Any],
                 grace_s: float = ORPHAN_GRACE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.store = store
        self.send = send
        self.grace_s = grace_s
        self.clock = clock
        self._first_seen: dict[tuple[str, str], float] = {}
        self._head: tuple[str | None, float] = (None, 0.0)

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
        return handled + self._wake_if_stalled(now)

    def _wake_if_stalled(self, now: float) -> list[str]:
        """One message per idle worker when the same job has been first in the queue for
        ``STALL_S`` with a worker idle. Returns the head's id when it sent any."""
        head = self.store.queue_head()
        if head != self._head[0]:
            self._head = (head, now)
            return []
        idle = len(self.store.workers.live()) - len(self.store.running_ids())
        if head is None or idle <= 0 or now - self._head[1] < STALL_S:
            return []
        log.warning("queue stalled on job %s with %d idle worker(s): waking them", head, idle)
        for _ in range(idle):
            self.send(head)
        self._head = (head, now)
        return [head]
