"""Job state: one Redis hash per job, mirrored to ``<job folder>/state.json``.

Redis answers the hot path (a poll is one HGETALL); ``state.json`` lets a job survive a Redis
restart: a job Redis has forgotten is read back from its folder and re-seeded. Used by the API and
the worker alike, so it imports neither FastAPI nor Celery.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import redis
import redis.asyncio as aioredis
from pydantic import BaseModel, Field, ValidationError

from app.schemas import ErrorDetail, JobState

log = logging.getLogger(__name__)

JOB_ID_RE = re.compile(r"^[0-9a-f]{8}-[0-9a-f]{4}-4[0-9a-f]{3}-[89ab][0-9a-f]{3}-[0-9a-f]{12}$")
STATE_FILE = "state.json"
TMP_PREFIX = ".upload-"
PREFIX = "cadnerf"
ANON_OWNER = "-"
RUNNING_KEY = f"{PREFIX}:running"  # ids of jobs in state running
QUEUE_KEY = f"{PREFIX}:queue"  # sorted set: ids of queued jobs, scored by enqueue time
WORKERS_KEY = f"{PREFIX}:workers"  # sorted set: worker name -> expiry (Redis server time)
TOMBSTONE_TTL_S = 7 * 24 * 3600

# Conditional HSET: only while the job exists and (when ARGV[1] is not empty) is in one of the
# comma-separated states, so a deleted job is never half re-created by a late worker update.
_UPDATE_LUA = """
if redis.call('exists', KEYS[1]) == 0 then return 0 end
if ARGV[1] ~= '' then
  local s = redis.call('hget', KEYS[1], 'state')
  local ok = false
  for st in string.gmatch(ARGV[1], '[^,]+') do if st == s then ok = true end end
  if not ok then return 0 end
end
redis.call('hset', KEYS[1], unpack(ARGV, 2))
return 1
"""


class JobRecord(BaseModel):
    """Everything the service keeps about one job (the Redis hash and state.json)."""

    id: str
    state: JobState = JobState.queued
    preset: str
    n_photos: int
    names: list[str] = Field(default_factory=list)
    owner: str = ANON_OWNER
    created_at: float
    started_at: float | None = None
    finished_at: float | None = None
    updated_at: float | None = None
    stage: str | None = None
    progress: float = 0.0
    eta_s: float | None = None
    error: str | None = None
    error_detail: ErrorDetail | None = None  # the failure, structured like an API error body
    webhook_url: str | None = None
    worker: str | None = None  # heartbeat name of the worker running it (while running)
    attempts: int = 0  # times it was queued again after its worker died

    def to_hash(self) -> dict[str, str]:
        """Flat string mapping for HSET (None -> empty string, lists -> JSON)."""
        return _encode(self.model_dump(mode="json"))

    @classmethod
    def from_hash(cls, raw: dict[str, str]) -> JobRecord:
        """Inverse of ``to_hash``."""
        data: dict[str, Any] = {k: (None if v == "" else v) for k, v in raw.items()}
        data["names"] = json.loads(data.get("names") or "[]")
        if data.get("error_detail") is not None:
            data["error_detail"] = json.loads(data["error_detail"])
        if data.get("progress") is None:
            data["progress"] = 0.0
        return cls.model_validate(data)


def _encode(fields: dict[str, Any]) -> dict[str, str]:
    out = {}
    for key, value in fields.items():
        if value is None:
            out[key] = ""
        elif isinstance(value, BaseModel):
            out[key] = value.model_dump_json(exclude_none=True)
        elif isinstance(value, list | dict):
            out[key] = json.dumps(value)
        else:
            out[key] = str(value)
    return out


def _mapping(record: JobRecord) -> dict[Any, Any]:
    return record.to_hash()


# --- expected job times and the queue -------------------------------------------------------
# Starting estimates in seconds on two CPU cores, before a worker has measured its own jobs
# (its measurements replace them after the first job of a preset; the speed observed during a
# job rescales the rest). Proportions from a measured `preview` job on 2 shared cores (load ~6):
# masks + retrieval 10 s, phase1 155 s, phase2 583 s; the table assumes an idle machine (~1/3).
# Here (not in the worker) because the API estimates the wait of queued jobs from them too.
DEFAULT_STAGE_SECONDS: dict[str, dict[str, float]] = {
    "test": {"masks": 0.5, "retrieval": 0.5, "phase1": 0.5, "phase2": 1.0, "phase3": 1.0,
             "render": 0.5, "export": 1.0},
    # `make run`'s demo job on 2 CPU cores (session 9, AMD EPYC: phase one 4 s, two 14 s,
    # three 111 s, views, orbit and mesh 11 s), rounded up for slower cores.
    "preview": {"masks": 3, "retrieval": 3, "phase1": 6, "phase2": 20, "phase3": 150,
                "render": 10, "export": 10},
    "standard": {"masks": 4, "retrieval": 4, "phase1": 250, "phase2": 1500, "phase3": 4000,
                 "render": 120, "export": 90},
    "paper": {"masks": 3, "retrieval": 3, "phase1": 300, "phase2": 5000, "phase3": 15000,
              "render": 200, "export": 200},
}
HISTORY_DEVICES = ("cuda", "cpu")  # where to look for measured times when the device is "auto"


def stage_times_key(preset: str, device: str) -> str:
    """Redis hash of measured seconds per stage for one preset on one kind of device.

    ``QUEUE_LUA`` builds the same key from ``PREFIX``.
    """
    return f"{PREFIX}:stage_seconds:{preset}:{device}"


def stage_table(preset: str, measured: Mapping[str, str | float]) -> dict[str, float]:
    """Expected seconds per stage: the measured values where known, else the default table."""
    table = dict(DEFAULT_STAGE_SECONDS.get(preset, DEFAULT_STAGE_SECONDS["standard"]))
    for stage, seconds in measured.items():
        if stage in table:
            table[stage] = max(float(seconds), 1e-3)
    return table


def expected_job_seconds(preset: str, measured: Mapping[str, str | float]) -> float | None:
    """Expected seconds of a whole job of ``preset``; None while no job of it was measured."""
    if not measured:
        return None
    return sum(stage_table(preset, measured).values())


def history_devices(device: str) -> tuple[str, ...]:
    """The devices whose measured times apply to workers configured with ``device``."""
    return HISTORY_DEVICES if device == "auto" else (device,)


# Place of a queued job and what is ahead of it, read in one call. Entries of the queue order
# whose job is no longer queued (a stale entry) are skipped. Returns false when the job is not in
# the queue, else {own preset, presets of the queued jobs ahead, running jobs as flat
# (preset, eta_s) pairs, live workers, measured stage times as flat (preset, flat hash) pairs}.
QUEUE_LUA = """
local rank = redis.call('zrank', KEYS[1], ARGV[1])
if not rank then return false end
local prefix = ARGV[2]
local function job(id, ...) return redis.call('hmget', prefix .. ':job:' .. id, ...) end
local own = job(ARGV[1], 'state', 'preset')
if own[1] ~= 'queued' or not own[2] then return false end
local presets, seen = {}, {}
local function want(p)
  if not seen[p] then seen[p] = true; presets[#presets + 1] = p end
end
want(own[2])
local ahead = {}
if rank > 0 then
  for _, id in ipairs(redis.call('zrange', KEYS[1], 0, rank - 1)) do
    local h = job(id, 'state', 'preset')
    if h[1] == 'queued' and h[2] then ahead[#ahead + 1] = h[2]; want(h[2]) end
  end
end
local running = {}
for _, id in ipairs(redis.call('smembers', KEYS[3])) do
  local h = job(id, 'state', 'preset', 'eta_s')
  if h[1] == 'running' and h[2] then
    running[#running + 1] = h[2]; running[#running + 1] = h[3] or ''; want(h[2])
  end
end
local history = {}
for _, p in ipairs(presets) do
  local found = {}
  for i = 3, #ARGV do
    found = redis.call('hgetall', prefix .. ':stage_seconds:' .. p .. ':' .. ARGV[i])
    if #found > 0 then break end
  end
  history[#history + 1] = p
  history[#history + 1] = found
end
local t = redis.call('time')
local workers = redis.call('zcount', KEYS[2], tonumber(t[1]) + tonumber(t[2]) / 1e6, '+inf')
return {own[2], ahead, running, workers, history}
"""


def _text(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


@dataclass(frozen=True)
class QueueEstimate:
    """Where a queued job stands.

    ``position``: queued jobs ahead of it (0 = next). ``eta_s``: expected seconds until it is
    done = (seconds left of the running jobs + expected seconds of the queued jobs ahead) /
    live workers (at least 1) + its own expected seconds; None while a preset involved has no
    measured job times yet.
    """

    position: int
    eta_s: float | None
    workers: int

    @classmethod
    def from_reply(cls, raw: Any) -> QueueEstimate | None:
        """Parse the reply of ``QUEUE_LUA`` (None: the job is not queued)."""
        if not raw:
            return None
        own, ahead, running, workers, history = raw
        expected: dict[str, float | None] = {}
        for i in range(0, len(history), 2):
            flat = [_text(v) for v in history[i + 1]]
            preset = _text(history[i])
            expected[preset] = expected_job_seconds(preset, dict(zip(flat[::2], flat[1::2],
                                                                     strict=True)))
        ahead = [_text(p) for p in ahead]
        backlog: list[float | None] = [expected.get(p) for p in ahead]
        for i in range(0, len(running), 2):
            left = _text(running[i + 1])
            backlog.append(float(left) if left else expected.get(_text(running[i])))
        own_s = expected.get(_text(own))
        n_workers = int(workers)
        eta = None
        if own_s is not None and all(b is not None for b in backlog):
            eta = round(sum(b for b in backlog if b is not None) / max(n_workers, 1) + own_s, 1)
        return cls(position=len(ahead), eta_s=eta, workers=n_workers)


_QUEUE_KEYS = [QUEUE_KEY, WORKERS_KEY, RUNNING_KEY]


async def queue_estimate_async(client: aioredis.Redis, job_id: str,
                               devices: Sequence[str] = HISTORY_DEVICES) -> QueueEstimate | None:
    """``JobStore.queue_estimate`` on an asyncio client (the status hot path): one call."""
    script = client.register_script(QUEUE_LUA)
    raw = await script(keys=_QUEUE_KEYS, args=[job_id, PREFIX, *devices])
    return QueueEstimate.from_reply(raw)


def is_job_id(value: str) -> bool:
    """True for a canonical lower-case uuid4 string (the only ids that map to folders)."""
    return bool(JOB_ID_RE.match(value))


def connect_async(url: str) -> aioredis.Redis:
    """An asyncio Redis client (the status hot path), configured like ``connect``."""
    return aioredis.Redis.from_url(url, decode_responses=True, socket_timeout=10,
                                   socket_connect_timeout=3, health_check_interval=30)


def connect(url: str) -> redis.Redis:
    """A Redis client with short timeouts and decoded strings.

    Args:
        url: redis://, rediss:// or unix:// URL.

    Returns:
        The client (connections are opened lazily).
    """
    return redis.Redis.from_url(url, decode_responses=True, socket_timeout=10,
                                socket_connect_timeout=3, health_check_interval=30)


class JobStore:
    """Job records in Redis, mirrored to each job folder's state.json."""

    def __init__(self, client: redis.Redis, data_root: Path) -> None:
        self.r = client
        self.data_root = Path(data_root)
        self._update = self.r.register_script(_UPDATE_LUA)
        self._queue = self.r.register_script(QUEUE_LUA)

    # --- keys and paths -------------------------------------------------------------------
    @staticmethod
    def job_key(job_id: str) -> str:
        """The job's Redis hash."""
        return f"{PREFIX}:job:{job_id}"

    @staticmethod
    def index_key(owner: str) -> str:
        """Sorted set of an owner's job ids, scored by creation time."""
        return f"{PREFIX}:jobs:{owner}"

    @staticmethod
    def cancel_key(job_id: str) -> str:
        """Flag the worker's cancel check reads."""
        return f"{PREFIX}:cancel:{job_id}"

    @staticmethod
    def deleted_key(job_id: str) -> str:
        """Tombstone of a deleted job (a late worker must not bring it back)."""
        return f"{PREFIX}:deleted:{job_id}"

    def job_dir(self, job_id: str) -> Path:
        """The job's folder; raises ValueError for anything but a job id (no path tricks)."""
        if not is_job_id(job_id):
            raise ValueError(f"not a job id: {job_id!r}")
        return self.data_root / job_id

    # --- records --------------------------------------------------------------------------
    def create(self, record: JobRecord) -> None:
        """Store a new job (its folder must already exist) and mirror it to state.json.

        A queued job also joins the queue order (``QUEUE_KEY``) in the same transaction.
        """
        pipe = self.r.pipeline()
        pipe.hset(self.job_key(record.id), mapping=_mapping(record))
        pipe.zadd(self.index_key(record.owner), {record.id: record.created_at})
        if record.state == JobState.queued:
            pipe.zadd(QUEUE_KEY, {record.id: record.created_at})
        pipe.execute()
        self.write_state_file(record)

    def get(self, job_id: str) -> JobRecord | None:
        """The job's record: one HGETALL, or state.json (re-seeding Redis) when Redis lost it."""
        if not is_job_id(job_id):
            return None
        raw = self.r.hgetall(self.job_key(job_id))
        if raw:
            return JobRecord.from_hash(raw)  # type: ignore[arg-type]
        record = self.read_state_file(job_id)
        if record is not None:
            self.reseed(record)
        return record

    def reseed(self, record: JobRecord) -> None:
        """Put a record read from disk back into Redis."""
        pipe = self.r.pipeline()
        pipe.hset(self.job_key(record.id), mapping=_mapping(record))
        pipe.zadd(self.index_key(record.owner), {record.id: record.created_at})
        if record.state == JobState.running:  # scanned for a dead worker (app.recovery)
            pipe.sadd(RUNNING_KEY, record.id)
        if record.state == JobState.queued:  # its place in the queue, as near as we know
            pipe.zadd(QUEUE_KEY, {record.id: record.created_at}, nx=True)
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
        encoded = _encode({**fields, "updated_at": time.time()})
        argv: list[str] = [",".join(s.value for s in allowed_from)]
        for key, value in encoded.items():
            argv += [key, value]
        return bool(self._update(keys=[self.job_key(job_id)], args=argv))

    def list(self, owner: str, offset: int, limit: int) -> tuple[list[JobRecord], int]:
        """One page of an owner's jobs, newest first, and how many there are."""
        key = self.index_key(owner)
        ids: list[str] = self.r.zrevrange(key, offset, offset + limit - 1)  # type: ignore[assignment]
        total = int(self.r.zcard(key))  # type: ignore[arg-type]
        pipe = self.r.pipeline()
        for job_id in ids:
            pipe.hgetall(self.job_key(job_id))
        records = [JobRecord.from_hash(raw) for raw in pipe.execute() if raw]
        return records, total

    def delete(self, record: JobRecord) -> None:
        """Forget a job in Redis and remove its folder."""
        pipe = self.r.pipeline()
        pipe.delete(self.job_key(record.id), self.cancel_key(record.id))
        pipe.set(self.deleted_key(record.id), "1", ex=TOMBSTONE_TTL_S)
        pipe.zrem(self.index_key(record.owner), record.id)
        pipe.srem(RUNNING_KEY, record.id)
        pipe.zrem(QUEUE_KEY, record.id)
        pipe.execute()
        shutil.rmtree(self.job_dir(record.id), ignore_errors=True)

    # --- queue order ----------------------------------------------------------------------
    def join_queue(self, job_id: str, at: float | None = None) -> None:
        """Put a job (back) at the end of the queue order (e.g. a re-queued orphan)."""
        self.r.zadd(QUEUE_KEY, {job_id: time.time() if at is None else at})

    def leave_queue(self, job_id: str) -> None:
        """Take a job out of the queue order (it started, or ended before starting)."""
        self.r.zrem(QUEUE_KEY, job_id)

    def queue_estimate(self, job_id: str,
                       devices: Sequence[str] = HISTORY_DEVICES) -> QueueEstimate | None:
        """Place and expected wait of a queued job (one Redis call); None when not queued."""
        raw = self._queue(keys=_QUEUE_KEYS, args=[job_id, PREFIX, *devices])
        return QueueEstimate.from_reply(raw)

    def queue_estimates(self, job_ids: Sequence[str],
                        devices: Sequence[str] = HISTORY_DEVICES
                        ) -> dict[str, QueueEstimate]:
        """``queue_estimate`` of several jobs in one round trip (jobs not queued are left out)."""
        if not job_ids:
            return {}
        pipe = self.r.pipeline(transaction=False)
        for job_id in job_ids:
            self._queue(keys=_QUEUE_KEYS, args=[job_id, PREFIX, *devices], client=pipe)
        out = {}
        for job_id, raw in zip(job_ids, pipe.execute(), strict=True):
            estimate = QueueEstimate.from_reply(raw)
            if estimate is not None:
                out[job_id] = estimate
        return out

    # --- cancel flag ----------------------------------------------------------------------
    def request_cancel(self, job_id: str) -> None:
        """Ask the worker to stop this job at its next step."""
        self.r.set(self.cancel_key(job_id), "1", ex=7 * 24 * 3600)

    def cancel_requested(self, job_id: str) -> bool:
        """True once someone asked the job to stop, or the job was deleted.

        A job missing from Redis whose folder is still there was lost by a Redis restart (the
        API re-seeds it from state.json), not deleted.
        """
        pipe = self.r.pipeline()
        pipe.exists(self.cancel_key(job_id), self.deleted_key(job_id))
        pipe.exists(self.job_key(job_id))
        flags, exists = pipe.execute()
        if flags:
            return True
        return not exists and not (self.job_dir(job_id) / STATE_FILE).is_file()

    def was_deleted(self, job_id: str) -> bool:
        """True when the job was deleted (in the last ``TOMBSTONE_TTL_S``) or its folder is gone."""
        return bool(self.r.exists(self.deleted_key(job_id))) or not (
            self.job_dir(job_id) / STATE_FILE).is_file()

    # --- state.json -----------------------------------------------------------------------
    def write_state_file(self, record: JobRecord) -> None:
        """Atomically mirror a record into its folder (skipped when the folder is gone)."""
        folder = self.job_dir(record.id)
        if not folder.is_dir():
            return
        tmp = folder / f".{STATE_FILE}.{os.getpid()}.tmp"
        try:
            tmp.write_text(record.model_dump_json(indent=1))
            os.replace(tmp, folder / STATE_FILE)
        except OSError as exc:  # the folder was deleted under us: the job is gone anyway
            log.debug("could not mirror %s: %s", record.id, exc)

    def mirror(self, job_id: str) -> JobRecord | None:
        """Copy the Redis record to state.json; returns it (None if the job is gone)."""
        raw = self.r.hgetall(self.job_key(job_id))
        if not raw:
            return None
        record = JobRecord.from_hash(raw)  # type: ignore[arg-type]
        self.write_state_file(record)
        return record

    def read_state_file(self, job_id: str) -> JobRecord | None:
        """The record saved in the job folder, or None when absent or unreadable."""
        path = self.job_dir(job_id) / STATE_FILE
        try:
            return JobRecord.model_validate_json(path.read_text())
        except (OSError, ValidationError, ValueError):
            return None

    def iter_job_ids(self) -> Iterator[str]:
        """Ids of all job folders on disk."""
        if not self.data_root.is_dir():
            return
        for entry in self.data_root.iterdir():
            if entry.is_dir() and is_job_id(entry.name):
                yield entry.name


# --- worker heartbeats ----------------------------------------------------------------------
# Both scripts read Redis's own clock, so workers and API hosts need not agree on the time.
_BEAT_LUA = """
local t = redis.call('time')
local now = tonumber(t[1]) + tonumber(t[2]) / 1e6
redis.call('set', KEYS[1], ARGV[3], 'PX', ARGV[2])
redis.call('zadd', KEYS[2], now + tonumber(ARGV[2]) / 1000, ARGV[1])
redis.call('zremrangebyscore', KEYS[2], '-inf', now)
return 1
"""
_LIVE_LUA = """
local t = redis.call('time')
return redis.call('zrangebyscore', KEYS[1], tonumber(t[1]) + tonumber(t[2]) / 1e6, '+inf')
"""


def heartbeat_key(name: str) -> str:
    """Key a live worker refreshes (it expires when the worker stops beating)."""
    return f"{PREFIX}:worker:{name}"


def beat(client: redis.Redis, name: str, ttl_s: float, info: dict[str, Any]) -> None:
    """Announce a live worker for ``ttl_s`` seconds (its key, and its entry in the worker set)."""
    ttl_ms = str(max(1, int(ttl_s * 1000)))
    client.eval(_BEAT_LUA, 2, heartbeat_key(name), WORKERS_KEY, name, ttl_ms, json.dumps(info))


def forget_worker(client: redis.Redis, name: str) -> None:
    """Remove a stopping worker at once (readiness drops without waiting for the TTL)."""
    pipe = client.pipeline()
    pipe.delete(heartbeat_key(name))
    pipe.zrem(WORKERS_KEY, name)
    pipe.execute()


def live_workers(client: redis.Redis) -> list[str]:
    """Names of the workers whose heartbeat has not expired (one cheap call, no key scan)."""
    names = client.eval(_LIVE_LUA, 1, WORKERS_KEY)
    return sorted(str(n) for n in names)  # type: ignore[union-attr]
