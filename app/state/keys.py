"""Every Redis key the service uses: the one place their names are spelled.

Callers (and the Lua scripts, through KEYS) get key names from these functions only.
"""

from __future__ import annotations

PREFIX = "cadnerf"
QUEUE = f"{PREFIX}:queue"  # sorted set: ids of queued jobs, scored by fair order (scripts.py)
FAIR_CLOCK = f"{PREFIX}:fair:clock"  # round of the last job started (fair order's virtual time)
FAIR_LAST = f"{PREFIX}:fair:last"  # hash: owner -> round of its last queued job
FAIR_SEQ = f"{PREFIX}:fair:seq"  # counter: arrival order inside a round
RUNNING = f"{PREFIX}:running"  # set: ids of jobs in state running (scanned for orphans)
WORKERS = f"{PREFIX}:workers"  # sorted set: live worker name -> expiry (Redis server time)


def job(job_id: str) -> str:
    """The job's record (a hash)."""
    return f"{PREFIX}:job:{job_id}"


def owner_jobs(owner: str) -> str:
    """Sorted set of an owner's job ids, scored by creation time."""
    return f"{PREFIX}:jobs:{owner}"


def cancel(job_id: str) -> str:
    """Flag the worker's cancel check reads."""
    return f"{PREFIX}:cancel:{job_id}"


def deleted(job_id: str) -> str:
    """Tombstone of a deleted job (a late worker must not bring it back)."""
    return f"{PREFIX}:deleted:{job_id}"


def claim(job_id: str) -> str:
    """Who runs the job right now (expires unless its worker's heartbeat refreshes it)."""
    return f"{PREFIX}:claim:{job_id}"


def worker(name: str) -> str:
    """Key a live worker refreshes (it expires when the worker stops beating)."""
    return f"{PREFIX}:worker:{name}"


def stage_seconds(device: str) -> str:
    """Hash of measured seconds on one kind of device, field ``<preset>/<stage>``."""
    return f"{PREFIX}:stage_seconds:{device}"


def uploads(owner: str) -> str:
    """Sorted set of an owner's submissions in the last minute, scored by time."""
    return f"{PREFIX}:uploads:{owner}"
