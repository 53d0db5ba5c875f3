"""Fair use per key: what an owner uses now, its limits, and whether a new job may come in.

An owner is the hash of an API key, or the anonymous owner on an open server (one owner for
all anonymous callers). Queued, running and finished-today counts are read from the owner's
records (no counter to drift through restarts); stored bytes from its job data where it lives
(the job folders, or the objects in the store).
"""

from __future__ import annotations

import math
import time
import uuid
from dataclasses import dataclass

import redis

from app.core import JobStorage
from app.settings import MB, Settings
from app.state import keys, scripts
from app.state.records import JobState

UPLOAD_WINDOW_S = 60.0
QUEUED_RETRY_S = 30  # a queued job of the key starts at the earliest after its turn: ask again
QUEUE_FULL_RETRY_S = 60


@dataclass(frozen=True)
class Limits:
    """Per-key limits and the global queue cap (0 = no limit)."""

    queued: int
    running: int
    uploads_per_minute: int
    stored_bytes: int
    queue_length: int

    @classmethod
    def of(cls, settings: Settings) -> Limits:
        """The limits a deployment's settings give."""
        return cls(queued=settings.max_queued_per_key, running=settings.max_running_per_key,
                   uploads_per_minute=settings.max_uploads_per_minute,
                   stored_bytes=int(settings.max_stored_mb_per_key * MB),
                   queue_length=settings.max_queue_length)


@dataclass(frozen=True)
class Usage:
    """What one owner uses now."""

    queued: int
    running: int
    done_today: int  # jobs that reached a final state since 00:00 UTC
    bytes_stored: int
    oldest_finished_at: float | None  # the first of its jobs the retention will remove


@dataclass(frozen=True)
class Refusal:
    """Why a submission is refused: the limit, its value, the current use, when it frees up.

    ``status``: 429 for a per-key limit, 503 for the global queue cap.
    """

    status: int
    limit: str
    maximum: int
    current: int
    retry_after_s: int
    message: str


class UsageMeter:
    """Reads an owner's usage and applies the limits at the door of a submission.

    Args:
        client: the Redis client.
        storage: where the job data lives (``cadnerf_core.jobfolder`` storage).
    """

    def __init__(self, client: redis.Redis, storage: JobStorage) -> None:
        self._r = client
        self.storage = storage
        self._rate = client.register_script(scripts.RATE)

    def usage(self, owner: str, now: float | None = None, with_bytes: bool = True) -> Usage:
        """The owner's queued, running and finished-today jobs and its stored bytes.

        Args:
            owner: the owner.
            now: the current time (default: ``time.time()``).
            with_bytes: add up the owner's job data for ``bytes_stored`` (else 0).
        """
        now = time.time() if now is None else now
        midnight = now - now % 86400
        ids: list[str] = self._r.zrange(keys.owner_jobs(owner), 0, -1)  # type: ignore[assignment]
        pipe = self._r.pipeline(transaction=False)
        for job_id in ids:
            pipe.hmget(keys.job(job_id), ["state", "finished_at"])
        counts = {state: 0 for state in JobState}
        done_today, oldest, stored = 0, None, 0
        for job_id, (state, finished) in zip(ids, pipe.execute(), strict=True):
            if not state:
                continue
            counts[JobState(state)] += 1
            stored += self.storage.job_bytes(job_id) if with_bytes else 0
            if finished and JobState(state).terminal:
                done_today += float(finished) >= midnight
                oldest = float(finished) if oldest is None else min(oldest, float(finished))
        return Usage(queued=counts[JobState.queued], running=counts[JobState.running],
                     done_today=done_today, bytes_stored=stored, oldest_finished_at=oldest)

    def queue_length(self) -> int:
        """Queued jobs of all owners."""
        return int(self._r.zcard(keys.QUEUE))  # type: ignore[arg-type]

    def admit(self, owner: str, limits: Limits, retention_s: float) -> Refusal | None:
        """Check a new submission against the limits; None when it may come in.

        The rate limit is checked last, so only submissions that pass every other limit use
        up one of the minute's slots.
        """
        length = self.queue_length()
        if limits.queue_length and length >= limits.queue_length:
            return Refusal(503, "queue_length", limits.queue_length, length, QUEUE_FULL_RETRY_S,
                           "the service's queue is full")
        use = self.usage(owner, with_bytes=bool(limits.stored_bytes))
        if limits.queued and use.queued >= limits.queued:
            return Refusal(429, "queued_jobs", limits.queued, use.queued, QUEUED_RETRY_S,
                           f"this key has {use.queued} jobs queued (at most {limits.queued})")
        if limits.stored_bytes and use.bytes_stored >= limits.stored_bytes:
            frees = (retention_s - (time.time() - use.oldest_finished_at)
                     if use.oldest_finished_at is not None else retention_s)
            return Refusal(429, "stored_bytes", limits.stored_bytes, use.bytes_stored,
                           max(1, math.ceil(frees)),
                           "this key's jobs hold too much storage; delete some")
        if limits.uploads_per_minute:
            wait = float(self._rate(keys=[keys.uploads(owner)],  # type: ignore[arg-type]
                                    args=[uuid.uuid4().hex, UPLOAD_WINDOW_S,
                                          limits.uploads_per_minute]))
            if wait >= 0:
                return Refusal(429, "uploads_per_minute", limits.uploads_per_minute,
                               limits.uploads_per_minute, max(1, math.ceil(wait)),
                               f"this key sent {limits.uploads_per_minute} jobs in the last "
                               "minute")
        return None

    def uploads_last_minute(self, owner: str) -> int:
        """Submissions the owner started in the last minute (read only)."""
        since = time.time() - UPLOAD_WINDOW_S
        return int(self._r.zcount(keys.uploads(owner), since, "+inf"))  # type: ignore[arg-type]
