"""Where queued jobs stand: place in the queue order and expected seconds until done.

Two round trips: the queue order and the running set, then the records of the jobs involved,
the measured history and the live workers. The same reads serve the blocking client (the list)
and the asyncio one (the polling route).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import redis.asyncio as aioredis

from app.state import keys, scripts
from app.state.eta import expected_job_seconds, first_history, history_devices
from app.state.records import JobRecord, JobState, is_job_id

_FIELDS = ("state", "preset", "eta_s", "work")


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


def order_commands(pipe: Any) -> None:
    """First round: the queue order and the running set."""
    pipe.zrange(keys.QUEUE, 0, -1)
    pipe.smembers(keys.RUNNING)


def involved(order: Sequence[str], running: Sequence[str], targets: Sequence[str]) -> list[str]:
    """Jobs whose records an estimate of ``targets`` needs: the queue up to the last target,
    and the running jobs."""
    places = [order.index(t) for t in targets if t in order]
    return [*order[:max(places) + 1], *running] if places else []


def detail_commands(pipe: Any, ids: Sequence[str], devices: Sequence[str]) -> None:
    """Second round: those records, each device's history, the number of live workers."""
    for job_id in ids:
        pipe.hmget(keys.job(job_id), _FIELDS)
    for device in devices:
        pipe.hgetall(keys.stage_seconds(device))
    pipe.eval(scripts.LIVE, 1, keys.WORKERS)


def estimates(order: Sequence[str], running: Sequence[str], targets: Sequence[str],
              devices: Sequence[str], reply: Sequence[Any]) -> dict[str, QueueEstimate]:
    """The estimate of each queued target from the two rounds (targets not queued left out)."""
    ids = involved(order, running, targets)
    records = {i: dict(zip(_FIELDS, reply[n], strict=True)) for n, i in enumerate(ids)}
    histories = list(zip(devices, reply[len(ids):len(ids) + len(devices)], strict=True))
    workers = len(reply[-1])
    seconds: dict[tuple[str, str], float | None] = {}

    def expected(preset: str, work: str | None) -> float | None:
        """Expected seconds of a job of ``preset`` with ``work`` (its record's JSON field)."""
        if (preset, work or "") not in seconds:
            device, measured = first_history(histories, preset)
            seconds[preset, work or ""] = expected_job_seconds(
                preset, device, measured, json.loads(work) if work else None)
        return seconds[preset, work or ""]

    busy: list[float | None] = []
    for job_id in running:
        h = records.get(job_id, {})
        if h.get("state") == JobState.running and h.get("preset"):
            busy.append(float(h["eta_s"]) if h.get("eta_s") else expected(h["preset"],
                                                                          h.get("work")))
    out = {}
    for target in targets:
        own = records.get(target, {})
        if own.get("state") != JobState.queued or not own.get("preset"):
            continue
        ahead = [(records[i]["preset"], records[i].get("work"))
                 for i in order[:order.index(target)]
                 if records[i].get("state") == JobState.queued and records[i].get("preset")]
        backlog = [expected(p, w) for p, w in ahead] + busy
        own_s = expected(own["preset"], own.get("work"))
        eta = None
        if own_s is not None and all(b is not None for b in backlog):
            eta = round(sum(b for b in backlog if b is not None) / max(workers, 1) + own_s, 1)
        out[target] = QueueEstimate(position=len(ahead), eta_s=eta, workers=workers)
    return out


def read_estimates(client: Any, targets: Sequence[str],
                   devices: Sequence[str]) -> dict[str, QueueEstimate]:
    """``estimates`` read with a blocking client."""
    pipe = client.pipeline()
    order_commands(pipe)
    order, running = pipe.execute()
    running = sorted(running)
    pipe = client.pipeline(transaction=False)
    detail_commands(pipe, involved(order, running, targets), devices)
    return estimates(order, running, targets, devices, pipe.execute())


class AsyncJobReader:
    """The polling route's reads on an asyncio client: a record, a queued job's estimate."""

    def __init__(self, url: str, device: str) -> None:
        self._r = aioredis.Redis.from_url(url, decode_responses=True, socket_timeout=10,
                                          socket_connect_timeout=3, health_check_interval=30)
        self.devices = history_devices(device)

    async def get(self, job_id: str) -> JobRecord | None:
        """The record as Redis has it (one HGETALL); None when Redis does not have it."""
        if not is_job_id(job_id):
            return None
        raw = await self._r.hgetall(keys.job(job_id))  # type: ignore[misc]
        return JobRecord.from_hash({str(k): str(v) for k, v in raw.items()}) if raw else None

    async def queue_estimate(self, record: JobRecord) -> QueueEstimate | None:
        """Where a queued job stands; None for a job in any other state."""
        if record.state != JobState.queued:
            return None
        pipe = self._r.pipeline()
        order_commands(pipe)
        order, running = await pipe.execute()
        running = sorted(running)
        pipe = self._r.pipeline(transaction=False)
        detail_commands(pipe, involved(order, running, [record.id]), self.devices)
        reply = await pipe.execute()
        return estimates(order, running, [record.id], self.devices, reply).get(record.id)

    async def close(self) -> None:
        """Close the connections."""
        await self._r.aclose()
