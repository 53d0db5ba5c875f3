"""Queued jobs: their place in the queue order and the expected time until they are done."""

from __future__ import annotations

import asyncio
import json
import sys
import time
import types
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import redis
from fastapi.testclient import TestClient

from app import jobs
from app.settings import Settings
from app.state import (
    STAGES,
    AsyncJobReader,
    JobRecord,
    JobState,
    JobStore,
    StageHistory,
    Workers,
    connect,
    keys,
    scaled,
    stage_work,
)
from cadnerf_core.config import PRESETS, resolve_config
from tests.configs import TINY_PRESET, tiny_client_config, tiny_request_json

TEST_JOB_S = 2.0 * len(STAGES)  # the fake history: 2 s per stage


def _store(settings: Settings) -> JobStore:
    return JobStore(connect(settings.redis_url), settings.data_root)


def _job(store: JobStore, created_at: float, state: JobState = JobState.queued,
         preset: str = TINY_PRESET) -> JobRecord:
    record = JobRecord(id=str(uuid.uuid4()), preset=preset, n_photos=3, state=state,
                       names=["a.png", "b.png", "c.png"], created_at=created_at)
    store.job_dir(record.id).mkdir(parents=True)
    store.create(record)
    return record


def _history(client: redis.Redis, preset: str = TINY_PRESET, device: str = "cpu") -> None:
    """What workers would have measured: 2 s for every stage of ``preset``."""
    StageHistory(client).record(preset, device, {stage: 2.0 for stage in STAGES})


def _status(store: JobStore, settings: Settings, record: JobRecord) -> dict:
    fresh = store.get(record.id)
    assert fresh is not None
    return jobs.to_status(fresh, jobs.queue_estimate(store, fresh, settings)).model_dump()


def test_two_queued_jobs_show_their_position_and_eta(settings: Settings,
                                                      clean_redis: redis.Redis) -> None:
    store = _store(settings)
    now = time.time()
    first, second = _job(store, now), _job(store, now + 1)
    _history(clean_redis)
    Workers(clean_redis).beat("worker-a", 30)
    Workers(clean_redis).beat("worker-b", 30)
    a, b = _status(store, settings, first), _status(store, settings, second)
    assert a["queue_position"] == 0 and a["eta_s"] == pytest.approx(TEST_JOB_S)
    # One job ahead, shared by two workers, then its own run.
    assert b["queue_position"] == 1 and b["eta_s"] == pytest.approx(TEST_JOB_S / 2 + TEST_JOB_S)
    # The polling route's asyncio reader gives the same answer.

    async def fast() -> tuple[int, float | None]:
        reader = AsyncJobReader(settings.redis_url, settings.device)
        try:
            estimate = await jobs.queue_estimate_fast(reader, second)
        finally:
            await reader.close()
        assert estimate is not None
        return estimate.position, estimate.eta_s

    assert asyncio.run(fast()) == (1, pytest.approx(TEST_JOB_S * 1.5))
    # The list: every queued job's estimate, in one round trip.
    listed = {s.id: s for s in jobs.statuses(store, [second, first], settings)}
    assert listed[first.id].queue_position == 0 and listed[second.id].queue_position == 1
    assert listed[second.id].eta_s == pytest.approx(TEST_JOB_S * 1.5)


def test_running_jobs_count_ahead_and_no_worker_counts_as_one(settings: Settings,
                                                             clean_redis: redis.Redis) -> None:
    store = _store(settings)
    now = time.time()
    running = _job(store, now - 5, JobState.running)
    store.update(running.id, eta_s=10.0)
    store.mark_running(running.id, True)
    queued = _job(store, now)
    _history(clean_redis)
    status = _status(store, settings, queued)
    assert status["queue_position"] == 0  # running jobs are not in the queue
    assert status["eta_s"] == pytest.approx(10.0 + TEST_JOB_S)  # no live worker: divided by 1
    assert _status(store, settings, running)["queue_position"] is None


def test_without_measured_history_the_eta_stays_null(settings: Settings,
                                                     clean_redis: redis.Redis) -> None:
    store = _store(settings)
    now = time.time()
    _job(store, now, preset="standard")
    second = _job(store, now + 1)
    _history(clean_redis)  # this job's preset is known, the one ahead is not
    status = _status(store, settings, second)
    assert status["queue_position"] == 1 and status["eta_s"] is None
    # A worker configured for one device does not use the other device's history.
    _history(clean_redis, "standard", "cuda")
    assert _status(store, settings, second)["eta_s"] is not None
    cpu_only = settings.model_copy(update={"device": "cpu"})
    assert _status(store, cpu_only, second)["eta_s"] is None


def test_a_job_leaves_the_queue_when_it_is_cancelled_or_deleted(settings: Settings,
                                                               clean_redis: redis.Redis) -> None:
    store = _store(settings)
    now = time.time()
    first, second = _job(store, now), _job(store, now + 1)
    assert _status(store, settings, second)["queue_position"] == 1
    result = jobs.delete_job(store, first, wait_s=0.5)
    assert result.deleted and result.worker_stopped
    assert clean_redis.zscore(keys.QUEUE, first.id) is None
    assert _status(store, settings, second)["queue_position"] == 0
    # Cancelled but not yet deleted: no longer counted ahead.
    third = _job(store, now + 2)
    store.update(second.id, state=JobState.cancelled)
    assert _status(store, settings, third)["queue_position"] == 0


def test_a_job_leaves_the_queue_when_a_worker_starts_it(settings: Settings,
                                                       clean_redis: redis.Redis,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    from worker import runner

    store = _store(settings)
    now = time.time()
    first, second = _job(store, now), _job(store, now + 1)
    seen: dict[str, object] = {}

    def run_job(job_dir: Path, library: object, progress: object, device: str,
                mask_model: Path | None = None) -> None:
        seen["first_queued"] = clean_redis.zscore(keys.QUEUE, first.id)
        seen["second"] = _status(store, settings, second)["queue_position"]
        seen["first"] = _status(store, settings, first)["queue_position"]

    fake = types.ModuleType("cadnerf_core.pipeline")
    fake.run_job = run_job  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "cadnerf_core.pipeline", fake)
    monkeypatch.setattr(runner, "get_library", lambda root: None)
    cpu = settings.model_copy(update={"device": "cpu"})
    assert runner.execute(first.id, cpu, store)["state"] == "succeeded"
    assert seen == {"first_queued": None, "second": 0, "first": None}
    # Cancelled before it starts: it leaves the queue too.
    store.request_cancel(second.id)
    assert runner.execute(second.id, cpu, store)["state"] == "cancelled"
    assert clean_redis.zcard(keys.QUEUE) == 0


def test_a_queued_job_rejoins_the_queue_when_redis_lost_it(settings: Settings,
                                                           clean_redis: redis.Redis) -> None:
    store = _store(settings)
    now = time.time()
    first, second = _job(store, now), _job(store, now + 1)
    clean_redis.flushdb()  # Redis restarted empty; state.json is still there
    assert _status(store, settings, first)["queue_position"] == 0  # re-seeded
    assert _status(store, settings, second)["queue_position"] == 1


def test_the_api_reports_queue_position_and_eta(client: TestClient, clean_redis: redis.Redis,
                                                 photos: Callable[..., list[Any]]) -> None:
    """Through the routes: POST, GET and the list carry the position; a delete moves up."""
    _history(clean_redis)
    Workers(clean_redis).beat("worker-a", 30)
    shorter = {"phase3": {"steps": 3}, "export": {"orbit_size": 16}}
    config = {"config": tiny_request_json(**shorter)}
    first = client.post("/v1/jobs", files=photos(), data=config)
    second = client.post("/v1/jobs", files=photos(), data=config)
    assert first.status_code == 202 and second.status_code == 202, second.text
    assert first.json()["queue_position"] == 0
    assert second.json()["queue_position"] == 1
    tiny_s = sum(scaled({stage: 2.0 for stage in STAGES},
                        stage_work(tiny_client_config(**shorter))).values())
    assert tiny_s < TEST_JOB_S  # the overrides shrink phase three and the render
    assert second.json()["eta_s"] == pytest.approx(2 * tiny_s, abs=0.1)
    listed = {j["id"]: j for j in client.get("/v1/jobs").json()["items"]}
    assert listed[second.json()["id"]]["queue_position"] == 1
    assert client.delete(f"/v1/jobs/{first.json()['id']}").status_code == 200
    moved = client.get(f"/v1/jobs/{second.json()['id']}").json()
    assert moved["queue_position"] == 0 and moved["eta_s"] == pytest.approx(tiny_s, abs=0.1)


_PREVIEW = PRESETS[TINY_PRESET]


@pytest.mark.parametrize(("overrides", "stage", "low", "high"), [
    # Ten times phase three's steps: its 2 s become 20 s.
    ({"phase3.steps": 10 * _PREVIEW.phase3.steps}, "phase3", 10.0, 10.0),
    # Twice phase two's steps: phase two costs twice as much.
    ({"phase2.steps": 2 * _PREVIEW.phase2.steps}, "phase2", 2.0, 2.0),
    # Twice the orbit's side: four times its pixels; the views' pixels stay. The orbit holds
    # most of preview's rendered pixels, so the render stage grows by 2 to 4 times.
    ({"export.orbit_size": 2 * _PREVIEW.export.orbit_size}, "render", 2.0, 4.0),
    # Twice the working size: the views' pixels quadruple, the orbit's stay.
    ({"image_size": 2 * _PREVIEW.image_size}, "render", 1.0, 4.0),
    # Half the working size: fewer pixels to render, a shorter render stage.
    ({"image_size": _PREVIEW.image_size // 2}, "render", 0.25, 1.0),
], ids=["phase3.steps x10", "phase2.steps x2", "export.orbit_size x2", "image_size x2",
        "image_size /2"])
def test_the_eta_scales_with_the_overrides(client: TestClient, clean_redis: redis.Redis,
                                           photos: Callable[..., list[Any]],
                                           overrides: dict[str, Any], stage: str, low: float,
                                           high: float) -> None:
    """A queued job's estimate is the preset's 2 s a stage, the stage its override drives
    scaled by ``stage_work`` (between ``low`` and ``high`` times), the others as they were."""
    _history(clean_redis)
    Workers(clean_redis).beat("worker-a", 30)
    plain = {"config": json.dumps({"preset": TINY_PRESET})}
    first = client.post("/v1/jobs", files=photos(), data=plain)
    assert first.status_code == 202 and first.json()["eta_s"] == pytest.approx(TEST_JOB_S)
    client.delete(f"/v1/jobs/{first.json()['id']}")
    work = stage_work(resolve_config(TINY_PRESET, overrides))
    assert low <= work[stage] <= high, work
    assert all(ratio == 1.0 for name, ratio in work.items() if name != stage), work
    changed = {"config": json.dumps({"preset": TINY_PRESET, "overrides": overrides})}
    second = client.post("/v1/jobs", files=photos(), data=changed)
    assert second.status_code == 202, second.text
    expected = sum(scaled({name: 2.0 for name in STAGES}, work).values())
    assert expected == pytest.approx(TEST_JOB_S + 2.0 * (work[stage] - 1))
    assert second.json()["eta_s"] == pytest.approx(expected, abs=0.1)
