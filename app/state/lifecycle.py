"""A job's final state, written so that it survives Redis being away."""

from __future__ import annotations

import logging
import time
from typing import Any

import redis

from app.state.records import ErrorDetail, JobRecord, JobState
from app.state.store import JobStore

log = logging.getLogger(__name__)

FINISH_RETRY_S = 30.0  # how long the final state is retried while Redis is away


def finish_job(store: JobStore, record: JobRecord, state: JobState, error: str | None = None,
               detail: ErrorDetail | None = None,
               redis_wait_s: float = FINISH_RETRY_S) -> tuple[JobRecord, bool]:
    """Write a final state: state.json first (it survives Redis), then Redis.

    Redis is retried for ``redis_wait_s`` (after that the API re-seeds the job from
    state.json); the job leaves the running set and the queue order (it may end without
    starting, e.g. cancelled).

    Returns:
        The final record, and whether Redis has it (False also for a deleted job).
    """
    fields: dict[str, Any] = {"state": state, "finished_at": time.time(), "error": error,
                              "error_detail": detail, "worker": None}
    if state == JobState.succeeded:
        fields.update(progress=1.0, eta_s=0.0)
    else:
        fields.update(eta_s=None)
    final = store.latest(record).model_copy(update=fields)
    store.write_state_file(final)
    return final, _settle_retrying(store, final, fields, redis_wait_s)


def _settle_retrying(store: JobStore, final: JobRecord, fields: dict[str, Any],
                     wait_s: float) -> bool:
    """``store.settle``, retried with a growing delay for ``wait_s`` while Redis is away."""
    deadline = time.monotonic() + wait_s
    delay = 0.2
    while True:
        try:
            return store.settle(final, fields)
        except redis.RedisError as exc:
            if time.monotonic() + delay > deadline:
                log.error("job %s: Redis unavailable (%s); its final state is in state.json and "
                          "is read back from there", final.id, exc)
                return False
            log.warning("job %s: Redis unavailable (%s); retrying", final.id, exc)
            time.sleep(delay)
            delay = min(delay * 2, 2.0)
