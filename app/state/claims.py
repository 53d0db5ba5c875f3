"""Who runs what: per-job claims and worker heartbeats.

A worker claims a job before running it (the claim holds its heartbeat name for a short TTL
its heartbeat refreshes), so a duplicate delivery never runs a job twice at once, and a job
whose claim lapsed lost its worker.
"""

from __future__ import annotations

import json
from typing import Any

import redis

from app.state import keys, scripts

HEARTBEAT_TTL_S = 5.0  # a killed worker disappears from /readyz and its claims lapse after this
HEARTBEAT_EVERY_S = 1.5


def _ms(seconds: float) -> str:
    return str(max(1, int(seconds * 1000)))


class Claims:
    """Per-job claims: at most one worker holds a job at a time."""

    def __init__(self, client: redis.Redis) -> None:
        self._r = client
        self._claim = client.register_script(scripts.CLAIM)
        self._release = client.register_script(scripts.RELEASE)

    def take(self, job_id: str, worker: str, ttl_s: float = HEARTBEAT_TTL_S) -> bool:
        """Take (or refresh) the claim on a job; False when another worker holds it."""
        return bool(self._claim(keys=[keys.claim(job_id)], args=[worker, _ms(ttl_s)]))

    def holder(self, job_id: str) -> str | None:
        """The worker holding the job's claim, or None."""
        holder = self._r.get(keys.claim(job_id))
        return None if holder is None else str(holder)

    def release(self, job_id: str, worker: str) -> None:
        """Give up ``worker``'s claim (someone else's is left alone)."""
        self._release(keys=[keys.claim(job_id)], args=[worker])


class Workers:
    """Worker heartbeats: who is alive, read from Redis's own clock."""

    def __init__(self, client: redis.Redis) -> None:
        self._r = client
        self._beat = client.register_script(scripts.BEAT)
        self._live = client.register_script(scripts.LIVE)

    def beat(self, name: str, ttl_s: float = HEARTBEAT_TTL_S,
             info: dict[str, Any] | None = None) -> None:
        """Announce a live worker for ``ttl_s`` seconds."""
        self._beat(keys=[keys.worker(name), keys.WORKERS],
                   args=[name, _ms(ttl_s), json.dumps(info or {})])

    def forget(self, name: str) -> None:
        """Remove a stopping worker at once (readiness drops without waiting for the TTL)."""
        pipe = self._r.pipeline()
        pipe.delete(keys.worker(name))
        pipe.zrem(keys.WORKERS, name)
        pipe.execute()

    def forget_all(self) -> int:
        """Remove every heartbeat (a private Redis whose workers are all gone, e.g. the embedded
        one a killed ``serve`` saved); returns how many were listed."""
        names = [str(n) for n in self._r.zrange(keys.WORKERS, 0, -1)]  # type: ignore[union-attr]
        pipe = self._r.pipeline()
        for name in names:
            pipe.delete(keys.worker(name))
        pipe.delete(keys.WORKERS)
        pipe.execute()
        return len(names)

    def devices(self) -> list[str]:
        """The ``device`` each live worker announces in its heartbeat ("" when it names none)."""
        names = self.live()
        if not names:
            return []
        infos = self._r.mget([keys.worker(name) for name in names])
        return [_device(info) for info in infos]  # type: ignore[union-attr]

    def live(self) -> list[str]:
        """Names of the workers whose heartbeat has not expired (one call, no key scan)."""
        return sorted(str(n) for n in self._live(keys=[keys.WORKERS]))  # type: ignore[union-attr]


def _device(info: object) -> str:
    """The ``device`` field of a heartbeat's JSON info ("" when absent or unreadable)."""
    try:
        device = json.loads(str(info)).get("device", "") if info else ""
    except (ValueError, AttributeError):
        return ""
    return device if isinstance(device, str) else ""
