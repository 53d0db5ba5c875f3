"""Job records in Redis, mirrored to each job's ``state.json``, with the queue order, the
running set and the cancel flags.

Redis answers the hot path (a poll is one HGETALL); ``state.json`` lets a job survive a Redis
restart: a job Redis has forgotten is read back from where its data lives and re-seeded.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
import uuid
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import redis

from app.core import JobStorage, LocalStorage
from app.state import keys, scripts
from app.state.claims import Claims, Workers
from app.state.estimate import QueueEstimate, read_estimates
from app.state.eta import StageHistory, history_devices
from app.state.records import JobRecord, JobState, encode, is_job_id
from app.state.statefile import STATE_FILE, StateFiles
from app.state.usage import UsageMeter

log = logging.getLogger(__name__)

__all__ = ["STATE_FILE", "JobStore", "connect"]
TRASH_PREFIX = ".deleted-"  # a deleted job's folder, renamed away while it is removed
TOMBSTONE_TTL_S = 7 * 24 * 3600
CANCEL_TTL_S = 7 * 24 * 3600


def connect(url: str) -> redis.Redis:
    """A Redis client with short timeouts and decoded strings (connections open lazily).

    Args:
        url: redis://, rediss:// or unix:// URL.
    """
    return redis.Redis.from_url(url, decode_responses=True, socket_timeout=10,
                                socket_connect_timeout=3, health_check_interval=30)


class JobStore:
    """The job state: records, queue order, running set, cancel flags, claims, workers, history.

    Args:
        client: the Redis client (``connect``); closed by ``close``.
        data_root: the folder holding one folder per job (scratch copies with object storage).
        storage: where the job data lives (default: the data root itself).
    """

    def __init__(self, client: redis.Redis, data_root: Path,
                 storage: JobStorage | None = None) -> None:
        self._r = client
        self.data_root = Path(data_root)
        self.storage = storage or LocalStorage(self.data_root)
        self.claims = Claims(client)
        self.workers = Workers(client)
        self.history = StageHistory(client)
        self.usage = UsageMeter(client, self.storage)
        self.state_files = StateFiles(client, self.storage)
        self._update = client.register_script(scripts.UPDATE)
        self._start = client.register_script(scripts.START)
        self._requeue = client.register_script(scripts.REQUEUE)
        self._mark_running = client.register_script(scripts.MARK_RUNNING)
        self._enqueue = client.register_script(scripts.ENQUEUE)
        self._take = client.register_script(scripts.TAKE)
        self._hand_back = client.register_script(scripts.HAND_BACK)

    @classmethod
    def open(cls, url: str, data_root: Path, storage: JobStorage | None = None) -> JobStore:
        """A store on a new client of the Redis at ``url``."""
        return cls(connect(url), data_root, storage)

    def close(self) -> None:
        """Close the Redis connections."""
        self._r.close()

    def ping(self) -> bool:
        """True when Redis answers (raises ``redis.RedisError`` when it does not)."""
        return bool(self._r.ping())

    def job_dir(self, job_id: str) -> Path:
        """The job's folder; raises ValueError for anything but a job id (no path tricks)."""
        if not is_job_id(job_id):
            raise ValueError(f"not a job id: {job_id!r}")
        return self.data_root / job_id

    # --- records --------------------------------------------------------------------------
    def create(self, record: JobRecord) -> None:
        """Store a new job (its folder must exist), mirror it, and queue it when queued."""
        pipe = self._r.pipeline()
        pipe.hset(keys.job(record.id), mapping=record.to_hash())  # type: ignore[arg-type]
        pipe.zadd(keys.owner_jobs(record.owner), {record.id: record.created_at})
        if record.state == JobState.queued:
            self._queue_fairly(record, pipe)
        pipe.execute()
        self.write_state_file(record)

    def _queue_fairly(self, record: JobRecord, pipe: Any, front: bool = False) -> None:
        """Add the queued job to the queue in fair order between owners (``scripts.ENQUEUE``)."""
        self._enqueue(keys=[keys.QUEUE, keys.FAIR_CLOCK, keys.FAIR_LAST, keys.FAIR_SEQ],
                      args=[record.id, record.owner, "1" if front else "0", scripts.ROUND],
                      client=pipe)

    def get(self, job_id: str) -> JobRecord | None:
        """The job's record: one HGETALL, or state.json (re-seeding Redis) when Redis lost it."""
        if not is_job_id(job_id):
            return None
        raw = self._r.hgetall(keys.job(job_id))
        if raw:
            return JobRecord.from_hash(raw)  # type: ignore[arg-type]
        record = self.read_state_file(job_id)
        if record is None:
            return None
        if self._r.exists(keys.deleted(job_id)):  # a folder left behind: never brought back
            log.warning("job %s was deleted; its leftover folder is removed", job_id)
            self.remove_folder(job_id)
            return None
        self.reseed(record)
        return record

    def latest(self, record: JobRecord) -> JobRecord:
        """The newest record readable: Redis, else state.json, else ``record`` itself."""
        try:
            raw = self._r.hgetall(keys.job(record.id))
            if raw:
                return JobRecord.from_hash(raw)  # type: ignore[arg-type]
        except redis.RedisError as exc:
            log.debug("job %s: Redis unreadable (%s); using state.json", record.id, exc)
        return self.read_state_file(record.id) or record

    def reseed(self, record: JobRecord) -> None:
        """Put a record read from disk back into Redis (and its running set or queue order)."""
        pipe = self._r.pipeline()
        pipe.hset(keys.job(record.id), mapping=record.to_hash())  # type: ignore[arg-type]
        pipe.zadd(keys.owner_jobs(record.owner), {record.id: record.created_at})
        if record.state == JobState.running:  # scanned for a dead worker
            pipe.sadd(keys.RUNNING, record.id)
        if record.state == JobState.queued:  # its place in the queue: a started one first
            self._queue_fairly(record, pipe, front=record.started_at is not None)
        pipe.execute()
        log.info("re-seeded job %s from state.json", record.id)

    def update(self, job_id: str, allowed_from: Iterable[JobState] = (),
               **fields: Any) -> bool:
        """Set fields of an existing job atomically.

        Args:
            job_id: the job.
            allowed_from: apply only while the job is in one of these states (empty: any).
            fields: JobRecord fields to set.

        Returns:
            False when the job is gone or in another state (nothing was written).
        """
        argv: list[str] = [",".join(s.value for s in allowed_from)]
        argv += _pairs({**fields, "updated_at": time.time()})
        return bool(self._update(keys=[keys.job(job_id)], args=argv))

    def page(self, owner: str, offset: int, limit: int) -> tuple[list[JobRecord], int]:
        """One page of an owner's jobs, newest first, and how many there are."""
        index = keys.owner_jobs(owner)
        ids: list[str] = self._r.zrevrange(index, offset, offset + limit - 1)  # type: ignore[assignment]
        total = int(self._r.zcard(index))  # type: ignore[arg-type]
        pipe = self._r.pipeline()
        for job_id in ids:
            pipe.hgetall(keys.job(job_id))
        return [JobRecord.from_hash(raw) for raw in pipe.execute() if raw], total

    def delete(self, record: JobRecord) -> None:
        """Forget a job in Redis (leaving a tombstone) and remove its folder.

        The tombstone comes first (a worker's next cancel check sees it), then the folder is
        renamed away in one step and removed: from then on nothing can write under the job's
        path, since no writer creates a missing job folder (``cadnerf_core.jobfolder``).
        """
        pipe = self._r.pipeline()
        pipe.set(keys.deleted(record.id), "1", ex=TOMBSTONE_TTL_S)
        pipe.delete(keys.job(record.id), keys.cancel(record.id))
        pipe.zrem(keys.owner_jobs(record.owner), record.id)
        pipe.srem(keys.RUNNING, record.id)
        pipe.zrem(keys.QUEUE, record.id)
        pipe.execute()
        self.remove_folder(record.id)

    def remove_folder(self, job_id: str) -> None:
        """Remove the job's data: its objects in the store, if any, and its folder.

        The folder is renamed to a ``TRASH_PREFIX`` name (atomic), then removed; a file a late
        writer puts into the renamed folder is removed by ``remove_trash``. Objects the store
        cannot delete now are left to the retention (the tombstone marks them).
        """
        try:
            self.storage.remove(job_id)
        except OSError as exc:
            log.error("could not delete the stored data of job %s: %s", job_id, exc)
        folder = self.job_dir(job_id)
        trash = self.data_root / f"{TRASH_PREFIX}{job_id}-{uuid.uuid4().hex[:8]}"
        try:
            os.rename(folder, trash)
        except FileNotFoundError:
            return
        except OSError as exc:  # not renamable (storage trouble): remove it in place
            log.warning("could not rename %s away (%s); removing it in place", folder, exc)
            trash = folder
        shutil.rmtree(trash, ignore_errors=True)

    def remove_trash(self) -> int:
        """Remove what is left of deleted jobs' folders; returns how many were found."""
        found = 0
        if self.data_root.is_dir():
            for entry in self.data_root.glob(f"{TRASH_PREFIX}*"):
                found += 1
                shutil.rmtree(entry, ignore_errors=True)
        return found

    # --- transitions ----------------------------------------------------------------------
    def start(self, job_id: str, worker: str, started_at: float) -> bool:
        """Queued (or running again after a re-delivery) -> running on ``worker``.

        The job joins the running set and leaves the queue order in the same step. Returns
        False when it is in another state (it leaves the queue order all the same).
        """
        fields = {"state": JobState.running, "started_at": started_at, "error": None,
                  "error_detail": None, "worker": worker, "updated_at": time.time()}
        argv = [job_id, *_pairs(fields)]
        started = bool(self._start(keys=[keys.job(job_id), keys.RUNNING, keys.QUEUE], args=argv))
        if started:
            self.mirror(job_id)
        return started

    def take_next(self, worker: str, claim_ttl_s: float, running_limit: int = 0,
                  scan: int = 16) -> str | None:
        """Start the next job in fair order on ``worker``: claimed, running, out of the queue.

        Args:
            worker: the worker's heartbeat name (it holds the claim).
            claim_ttl_s: the claim's lifetime until the worker's heartbeat refreshes it.
            running_limit: jobs one owner may run at once (0: no limit); an owner at it is
                passed over (checked before the atomic take: two workers taking at the same
                instant may both pass it).
            scan: queue heads tried per read (others may take the first ones meanwhile).

        Returns:
            The job id, or None when no queued job is left.
        """
        fields = {"state": JobState.running, "error": None, "error_detail": None,
                  "worker": worker, "updated_at": time.time()}
        while True:
            heads: list[str] = self._r.zrange(keys.QUEUE, 0, scan - 1)  # type: ignore[assignment]
            if not heads:
                return None
            changed = False
            for job_id in self._within_running_limit(heads, running_limit):
                taken = int(self._take(  # type: ignore[arg-type]
                    keys=[keys.QUEUE, keys.job(job_id), keys.claim(job_id), keys.RUNNING,
                          keys.FAIR_CLOCK],
                    args=[job_id, worker, str(max(1, int(claim_ttl_s * 1000))),
                          f"{time.time():.6f}", scripts.ROUND, *_pairs(fields)]))
                if taken == 1:
                    self.mirror(job_id)
                    return job_id
                changed = changed or taken != -2
            if not changed:  # every head is held by another worker: leave them to it
                return None

    def _within_running_limit(self, heads: list[str], limit: int) -> list[str]:
        """The queue heads whose owner runs fewer than ``limit`` jobs (all when 0)."""
        if not limit:
            return heads
        running = self.running_ids()
        pipe = self._r.pipeline(transaction=False)
        for job_id in [*running, *heads]:
            pipe.hget(keys.job(job_id), "owner")
        owners = pipe.execute()
        busy: dict[str, int] = {}
        for owner in owners[:len(running)]:
            busy[owner] = busy.get(owner, 0) + 1
        return [job_id for job_id, owner in zip(heads, owners[len(running):], strict=True)
                if busy.get(owner, 0) < limit]

    def settle(self, final: JobRecord, fields: dict[str, Any]) -> bool:
        """Write a final state to Redis: the job leaves the running set and the queue order.

        A job Redis has lost (restarted empty) is re-seeded from ``final`` unless it was
        deleted. Returns True once Redis has the job. Raises ``redis.RedisError``.
        """
        if not self.update(final.id, **fields):
            if self.was_deleted(final.id):
                return False
            self.reseed(final)
        pipe = self._r.pipeline()
        pipe.srem(keys.RUNNING, final.id)
        pipe.zrem(keys.QUEUE, final.id)
        pipe.execute()
        return True

    def request_cancel(self, job_id: str) -> None:
        """Ask the worker to stop this job at its next step (or not to start it)."""
        self._r.set(keys.cancel(job_id), "1", ex=CANCEL_TTL_S)

    def cancel(self, job_id: str) -> None:
        """Ask a running job to stop; a queued one is cancelled at once and leaves the queue."""
        self.request_cancel(job_id)
        if self.update(job_id, allowed_from=(JobState.queued,), state=JobState.cancelled,
                       finished_at=time.time()):
            self._r.zrem(keys.QUEUE, job_id)

    def requeue_orphan(self, record: JobRecord, max_attempts: int, error: str) -> int:
        """Running -> queued (its attempts + 1), or failed with ``error`` at ``max_attempts``.

        Only while the job still is running on ``record.worker`` with no claim. Returns the
        attempts made so far, 0 when it failed, -1 when the job changed meanwhile.
        """
        argv = [record.id, record.worker or "", str(max_attempts), f"{time.time():.6f}", error]
        job_keys = [keys.job(record.id), keys.claim(record.id), keys.RUNNING, keys.QUEUE]
        outcome = int(self._requeue(keys=job_keys, args=argv))  # type: ignore[arg-type]
        if outcome >= 0:
            self.mirror(record.id)
        return outcome

    # --- running set, queue order, cancel flag ---------------------------------------------
    def running_ids(self) -> list[str]:
        """Ids in the running set (scanned for orphans)."""
        return sorted(str(i) for i in self._r.smembers(keys.RUNNING))  # type: ignore[union-attr]

    def mark_running(self, job_id: str, running: bool) -> None:
        """Add the job to (or remove it from) the running set; a deleted job is never added."""
        if running:
            self._mark_running(keys=[keys.deleted(job_id), keys.RUNNING], args=[job_id])
        else:
            self._r.srem(keys.RUNNING, job_id)

    def queue_head(self) -> str | None:
        """The id first in the queue order, or None when nothing waits."""
        head = self._r.zrange(keys.QUEUE, 0, 0)
        return str(head[0]) if head else None  # type: ignore[index]

    def leave_queue(self, job_id: str) -> None:
        """Take a job out of the queue order (it ended before starting)."""
        self._r.zrem(keys.QUEUE, job_id)

    def queue_estimates(self, job_ids: Sequence[str], device: str = "auto"
                        ) -> dict[str, QueueEstimate]:
        """Place and expected wait of queued jobs (two round trips); others are left out.

        Args:
            job_ids: the jobs.
            device: the workers' configured device (its measured history is used).
        """
        if not job_ids:
            return {}
        return read_estimates(self._r, job_ids, history_devices(device))

    def cancel_requested(self, job_id: str) -> bool:
        """True once someone asked the job to stop, or the job was deleted.

        A job missing from Redis whose folder is still there was lost by a Redis restart (the
        API re-seeds it from state.json), not deleted.
        """
        pipe = self._r.pipeline()
        pipe.exists(keys.cancel(job_id), keys.deleted(job_id))
        pipe.exists(keys.job(job_id))
        flags, exists = pipe.execute()
        if flags:
            return True
        return not exists and not self.state_files.exists(job_id)

    def was_deleted(self, job_id: str) -> bool:
        """True when the job was deleted (in the last ``TOMBSTONE_TTL_S``) or its data is gone."""
        return bool(self._r.exists(keys.deleted(job_id))) or not self.state_files.exists(job_id)

    def tombstoned(self, job_id: str) -> bool:
        """True when the job was deleted in the last ``TOMBSTONE_TTL_S``."""
        return bool(self._r.exists(keys.deleted(job_id)))

    def hand_back(self, job_id: str, worker: str) -> bool:
        """Running on ``worker`` -> queued at the front, claim released: the worker is stopping
        (not an attempt used up). False when the job is no longer running there."""
        handed = bool(self._hand_back(
            keys=[keys.job(job_id), keys.claim(job_id), keys.RUNNING, keys.QUEUE],
            args=[job_id, worker, f"{time.time():.6f}"]))
        if handed:
            self.mirror(job_id)
        return handed

    # --- state.json -----------------------------------------------------------------------
    def write_state_file(self, record: JobRecord) -> None:
        """Atomically mirror a record to its state.json (skipped when the job is gone)."""
        self.state_files.write(record)

    def mirror(self, job_id: str) -> JobRecord | None:
        """Copy the Redis record to state.json; returns it (None if the job is gone)."""
        raw = self._r.hgetall(keys.job(job_id))
        if not raw:
            return None
        record = JobRecord.from_hash(raw)  # type: ignore[arg-type]
        self.write_state_file(record)
        return record

    def read_state_file(self, job_id: str) -> JobRecord | None:
        """The record saved in the job's state.json, or None when absent or unreadable."""
        return self.state_files.read(job_id)

    def iter_job_ids(self) -> Iterator[str]:
        """Ids of all jobs with data: folders on disk, and jobs in the store."""
        seen = set()
        if self.data_root.is_dir():
            for entry in self.data_root.iterdir():
                if entry.is_dir() and is_job_id(entry.name):
                    seen.add(entry.name)
                    yield entry.name
        for job_id in self.storage.job_ids():
            if is_job_id(job_id) and job_id not in seen:
                yield job_id

    def last_written(self, job_id: str) -> float | None:
        """When the job's data last changed, here or in the store (None when it has none)."""
        times = [t for t in (self.storage.newest(job_id), _mtime(self.job_dir(job_id)))
                 if t is not None]
        return max(times) if times else None


def _mtime(path: Path) -> float | None:
    try:
        return path.stat().st_mtime
    except OSError:
        return None


def _pairs(fields: dict[str, Any]) -> list[str]:
    """Encoded fields as a flat field, value, ... list (HSET's arguments)."""
    return [item for pair in encode(fields).items() for item in pair]
