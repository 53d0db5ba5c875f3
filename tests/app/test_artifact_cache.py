"""Artifact downloads: cache headers, ETag revalidation, HEAD, Range errors as JSON.

Also the start-up warning of a service without API keys.
"""

from __future__ import annotations

import logging
import time
import uuid

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.routes.jobs import ARTIFACT_CACHE_CONTROL
from app.settings import Settings
from app.state import JobRecord, JobState, JobStore, connect
from tests.configs import TINY_PRESET

VIDEO = bytes(range(256)) * 8  # 2048 bytes


def _job(settings: Settings, state: JobState = JobState.succeeded) -> str:
    """A job in Redis and on disk with an orbit.mp4 and a mesh.glb; returns its artifacts URL."""
    record = JobRecord(id=str(uuid.uuid4()), state=state, preset=TINY_PRESET, n_photos=3,
                       created_at=time.time())
    folder = settings.data_root / record.id
    folder.mkdir(parents=True)
    (folder / "orbit.mp4").write_bytes(VIDEO)
    (folder / "mesh.glb").write_bytes(b"glTF" + bytes(60))
    JobStore(connect(settings.redis_url), settings.data_root).create(record)
    return f"/v1/jobs/{record.id}/artifacts"


def test_artifacts_are_cached_privately_and_revalidated_by_etag(client: TestClient,
                                                                settings: Settings) -> None:
    base = _job(settings)
    whole = client.get(f"{base}/orbit.mp4")
    assert whole.status_code == 200 and whole.content == VIDEO
    assert whole.headers["cache-control"] == ARTIFACT_CACHE_CONTROL
    etag = whole.headers["etag"]
    assert etag.startswith('"') and whole.headers["last-modified"]

    for header in (etag, f"W/{etag}", f'"other", {etag}', "*"):
        again = client.get(f"{base}/orbit.mp4", headers={"If-None-Match": header})
        assert again.status_code == 304, header
        assert again.content == b""
        assert again.headers["etag"] == etag
        assert again.headers["cache-control"] == ARTIFACT_CACHE_CONTROL
    changed = client.get(f"{base}/orbit.mp4", headers={"If-None-Match": '"other"'})
    assert changed.status_code == 200 and changed.content == VIDEO

    mesh = client.get(f"{base}/mesh.glb", headers={"If-None-Match": etag})
    assert mesh.status_code == 200 and mesh.headers["etag"] != etag  # per-file tags
    assert mesh.headers["cache-control"] == ARTIFACT_CACHE_CONTROL


def test_head_gives_the_headers_without_a_body(client: TestClient, settings: Settings) -> None:
    base = _job(settings)
    get = client.get(f"{base}/orbit.mp4")
    head = client.head(f"{base}/orbit.mp4")
    assert head.status_code == 200 and head.content == b""
    for name in ("content-type", "content-length", "etag", "last-modified", "cache-control",
                 "accept-ranges"):
        assert head.headers[name] == get.headers[name], name
    assert head.headers["content-length"] == str(len(VIDEO))
    mesh = client.head(f"{base}/mesh.glb")
    assert mesh.status_code == 200 and "attachment" in mesh.headers["content-disposition"]
    assert client.head(f"{base}/mesh.glb", headers={
        "If-None-Match": mesh.headers["etag"]}).status_code == 304
    part = client.head(f"{base}/orbit.mp4", headers={"Range": "bytes=0-9"})
    assert part.status_code == 206 and part.content == b""
    assert part.headers["content-range"] == "bytes 0-9/2048"
    assert client.head(f"{base}/orbit.gif").status_code == 404
    assert client.head(f"{base}/../state.json").status_code == 404


def test_head_of_an_unfinished_job_is_409(client: TestClient, settings: Settings) -> None:
    base = _job(settings, JobState.running)
    assert client.head(f"{base}/orbit.mp4").status_code == 409
    response = client.get(f"{base}/orbit.mp4")
    assert response.status_code == 409 and "cache-control" not in response.headers


def test_ranges_still_work_and_bad_ones_answer_json(client: TestClient,
                                                   settings: Settings) -> None:
    base = _job(settings)
    part = client.get(f"{base}/orbit.mp4", headers={"Range": "bytes=10-19"})
    assert part.status_code == 206 and part.content == VIDEO[10:20]
    assert part.headers["content-range"] == "bytes 10-19/2048"
    assert part.headers["cache-control"] == ARTIFACT_CACHE_CONTROL
    tail = client.get(f"{base}/orbit.mp4", headers={"Range": "bytes=-16"})
    assert tail.status_code == 206 and tail.content == VIDEO[-16:]

    beyond = client.get(f"{base}/orbit.mp4", headers={"Range": "bytes=5000-"})
    assert beyond.status_code == 416
    assert beyond.headers["content-type"] == "application/json"
    assert beyond.headers["content-range"] == "bytes */2048"
    error = beyond.json()["error"]
    assert error["code"] == "range_not_satisfiable" and "2048" in error["message"]
    assert error["hint"]

    malformed = client.get(f"{base}/orbit.mp4", headers={"Range": "items=0-1"})
    assert malformed.status_code == 400
    assert malformed.json()["error"]["code"] == "bad_range"
    assert malformed.json()["error"]["field"] == "range"

    # an If-Range that no longer matches means "send it all", as FileResponse does
    stale = client.get(f"{base}/orbit.mp4", headers={"Range": "bytes=5000-",
                                                     "If-Range": '"not-the-etag"'})
    assert stale.status_code == 200 and stale.content == VIDEO
    # a matching If-None-Match wins over the Range
    etag = client.head(f"{base}/orbit.mp4").headers["etag"]
    assert client.get(f"{base}/orbit.mp4", headers={"Range": "bytes=5000-",
                                                    "If-None-Match": etag}).status_code == 304


def test_the_api_description_lists_get_and_head_for_artifacts(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    operations = spec["paths"]["/v1/jobs/{job_id}/artifacts/{name}"]
    assert {"get", "head"} <= set(operations)
    assert operations["get"]["operationId"] != operations["head"]["operationId"]
    assert {"304", "416"} <= set(operations["get"]["responses"])


def _start(settings: Settings) -> None:
    with TestClient(create_app(settings)):
        pass


def test_an_open_service_warns_once_at_start_up(make_settings,
                                               caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="app.main"):
        _start(make_settings())
    warnings = [r for r in caplog.records
                if r.name == "app.main" and "no API keys" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING
    message = warnings[0].getMessage()
    assert "CADNERF_API_KEYS" in message and "delete every job" in message


def test_a_service_with_keys_does_not_warn(make_settings,
                                           caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="app.main"):
        _start(make_settings(api_keys="key-one"))
    assert not [r for r in caplog.records if "no API keys" in r.getMessage()]


def test_an_open_service_on_a_loopback_address_only_notes_it(
        make_settings, caplog: pytest.LogCaptureFixture) -> None:
    from app.main import warn_if_open

    with caplog.at_level(logging.INFO, logger="app.main"):
        warn_if_open(make_settings(), local_only=True)
    notes = [r for r in caplog.records if "no API keys" in r.getMessage()]
    assert len(notes) == 1 and notes[0].levelno == logging.INFO
