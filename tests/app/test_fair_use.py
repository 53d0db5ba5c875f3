"""Fair use per key: each limit answers 429 (the queue cap 503) with Retry-After and a body
naming it, stores nothing, and lets submissions in again once jobs end."""

from __future__ import annotations

import time
import uuid
from pathlib import Path

from fastapi.testclient import TestClient

from app.main import create_app
from app.settings import Settings
from app.state import ANON_OWNER, JobStore, keys
from worker import runner

ONE = {"Authorization": "Bearer key-one"}
TWO = {"Authorization": "Bearer key-two"}


def _post(client: TestClient, photos, headers: dict[str, str] | None = None):
    return client.post("/v1/jobs", files=photos(), headers=headers or {})


def _folders(settings: Settings) -> list[str]:
    return sorted(p.name for p in Path(settings.data_root).iterdir())


def _end_one(settings: Settings) -> None:
    """Let a worker take the next job (it fails at once: the test library has no models)."""
    store = JobStore.open(settings.redis_url, settings.data_root)
    try:
        token = str(uuid.uuid4())  # a message is a wake-up: its job need not be the one run
        assert runner.execute(token, settings, store)["state"] == "failed"
    finally:
        store.close()


def _refused(response, status: int, limit: str) -> dict:
    assert response.status_code == status, response.text
    retry = int(response.headers["Retry-After"])
    error = response.json()["error"]
    assert error["limit"] == limit and error["retry_after_s"] == retry and retry >= 1
    assert error["current"] >= error["maximum"] > 0
    return error


def test_queued_jobs_per_key(make_settings, photos) -> None:
    settings = make_settings(api_keys="key-one, key-two", max_queued_per_key=2,
                             max_uploads_per_minute=0)
    with TestClient(create_app(settings)) as client:
        assert [_post(client, photos, ONE).status_code for _ in range(2)] == [202, 202]
        before = _folders(settings)
        error = _refused(_post(client, photos, ONE), 429, "queued_jobs")
        assert error["code"] == "limit_reached" and error["current"] == 2
        assert _folders(settings) == before  # nothing stored, not even a staging folder
        assert _post(client, photos, TWO).status_code == 202  # another key is not held back
        _end_one(settings)
        assert _post(client, photos, ONE).status_code == 202


def test_uploads_per_minute(make_settings, photos, clean_redis) -> None:
    settings = make_settings(max_uploads_per_minute=2)
    with TestClient(create_app(settings)) as client:
        assert [_post(client, photos).status_code for _ in range(2)] == [202, 202]
        before = _folders(settings)
        error = _refused(_post(client, photos), 429, "uploads_per_minute")
        assert error["retry_after_s"] <= 60
        assert _folders(settings) == before
        window = keys.uploads(ANON_OWNER)  # a minute passes: the window's entries age out
        clean_redis.zadd(window, {m: time.time() - 61 for m in clean_redis.zrange(window, 0, -1)})
        assert _post(client, photos).status_code == 202


def test_stored_bytes_per_key(make_settings, photos) -> None:
    settings = make_settings(max_stored_mb_per_key=0.001, max_uploads_per_minute=0)
    with TestClient(create_app(settings)) as client:
        first = _post(client, photos)
        assert first.status_code == 202  # nothing stored yet
        before = _folders(settings)
        error = _refused(_post(client, photos), 429, "stored_bytes")
        assert error["maximum"] == 1048 and error["current"] > 1048
        assert _folders(settings) == before
        assert client.delete(f"/v1/jobs/{first.json()['id']}").status_code == 200
        assert _post(client, photos).status_code == 202


def test_the_queue_cap_answers_503(make_settings, photos) -> None:
    settings = make_settings(api_keys="key-one, key-two", max_queue_length=2,
                             max_uploads_per_minute=0)
    with TestClient(create_app(settings)) as client:
        assert [_post(client, photos, ONE).status_code for _ in range(2)] == [202, 202]
        error = _refused(_post(client, photos, TWO), 503, "queue_length")
        assert error["code"] == "queue_full"
        _end_one(settings)
        assert _post(client, photos, TWO).status_code == 202


def test_usage_and_info_show_the_limits(make_settings, photos) -> None:
    settings = make_settings(api_keys="key-one, key-two", max_queued_per_key=7,
                             max_uploads_per_minute=30)
    with TestClient(create_app(settings)) as client:
        for _ in range(3):
            assert _post(client, photos, ONE).status_code == 202
        _end_one(settings)
        usage = client.get("/v1/usage", headers=ONE).json()
        assert (usage["queued"], usage["running"], usage["done_today"]) == (2, 0, 1)
        assert usage["uploads_last_minute"] == 3 and usage["bytes_stored"] > 0
        assert usage["limits"]["queued_jobs"] == 7
        other = client.get("/v1/usage", headers=TWO).json()
        assert (other["queued"], other["bytes_stored"], other["uploads_last_minute"]) == (0, 0, 0)
        assert client.get("/v1/usage").status_code == 401
        info = client.get("/v1/info", headers=ONE).json()
        assert info["limits"] == usage["limits"] and "preset_times" in info
