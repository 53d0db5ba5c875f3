"""Redis away: jobs are read from their state.json (owner checked as strictly), else 503."""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

from fastapi.testclient import TestClient

from app.deps import STATE_SOURCE_HEADER
from app.embedded import free_port
from app.main import create_app
from app.settings import Settings, hash_key
from app.state import ANON_OWNER, JobRecord, JobState, JobStore, connect
from app.state.store import STATE_FILE
from cadnerf_core.jobfolder import RESULT, JobFolder
from tests.configs import TINY_PRESET
from tests.job_results import write_fake_result

VIDEO = bytes(range(256)) * 4


def _on_disk(settings: Settings, state: JobState, owner: str = ANON_OWNER,
             **fields: object) -> JobRecord:
    """A job folder with its state.json (and, once succeeded, its artifacts); no Redis."""
    record = JobRecord(id=str(uuid.uuid4()), state=state, preset=TINY_PRESET, n_photos=3,
                       names=[f"photo_{i}.png" for i in range(3)], owner=owner,
                       created_at=time.time() - 60, **fields)
    folder = settings.data_root / record.id
    folder.mkdir(parents=True)
    if state == JobState.succeeded:
        (folder / "orbit.mp4").write_bytes(VIDEO)
        write_fake_result(JobFolder(folder))
    JobStore(connect("redis://127.0.0.1:1/0"), settings.data_root).write_state_file(record)
    assert (folder / STATE_FILE).is_file()
    return record


def _redis_down(make_settings, **overrides: object) -> Settings:
    """Settings whose Redis URL points at a port nothing listens on."""
    settings: Settings = make_settings(redis_url=f"redis://127.0.0.1:{free_port()}/0",
                                       **overrides)
    return settings


def _error(response, status: int, code: str) -> None:
    assert response.status_code == status, response.text
    assert response.json()["error"]["code"] == code


def test_a_succeeded_job_is_served_from_disk_while_redis_is_down(make_settings) -> None:
    settings = _redis_down(make_settings)
    record = _on_disk(settings, JobState.succeeded, progress=1.0, stage="export",
                      started_at=time.time() - 50, finished_at=time.time() - 5)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        status = client.get(f"/v1/jobs/{record.id}")
        assert status.status_code == 200, status.text
        assert status.headers[STATE_SOURCE_HEADER] == "disk"
        body = status.json()
        assert body["state"] == "succeeded" and body["progress"] == 1.0
        assert body["finished_at"] == record.finished_at

        result = client.get(f"/v1/jobs/{record.id}/result")
        assert result.status_code == 200, result.text
        assert result.json() == json.loads((settings.data_root / record.id / RESULT).read_text())
        assert "orbit.mp4" in result.json()["artifacts"]

        video = client.get(f"/v1/jobs/{record.id}/artifacts/orbit.mp4")
        assert video.status_code == 200 and video.content == VIDEO
        part = client.get(f"/v1/jobs/{record.id}/artifacts/orbit.mp4",
                          headers={"Range": "bytes=0-9"})
        assert part.status_code == 206 and part.content == VIDEO[:10]

        # what needs Redis still says so, and changes nothing on disk
        _error(client.delete(f"/v1/jobs/{record.id}"), 503, "store_unavailable")
        _error(client.get("/v1/jobs"), 503, "store_unavailable")
    assert (settings.data_root / record.id / "orbit.mp4").is_file()


def test_another_owners_job_is_still_refused_from_disk(make_settings) -> None:
    settings = _redis_down(make_settings, api_keys="key-one, key-two")
    record = _on_disk(settings, JobState.succeeded, owner=hash_key("key-one"))
    one = {"Authorization": "Bearer key-one"}
    two = {"Authorization": "Bearer key-two"}
    paths = [f"/v1/jobs/{record.id}", f"/v1/jobs/{record.id}/result",
             f"/v1/jobs/{record.id}/artifacts/orbit.mp4"]
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        for path in paths:
            _error(client.get(path, headers=two), 404, "not_found")
            _error(client.get(path), 401, "unauthorized")
            assert client.get(path, headers=one).status_code == 200, path
        head = client.head(paths[2], headers=two)
        assert head.status_code == 404 and head.content == b""


def test_an_anonymous_job_is_refused_to_a_key_holder_from_disk(make_settings) -> None:
    settings = _redis_down(make_settings, api_keys="key-one")
    record = _on_disk(settings, JobState.succeeded)  # owner "-", from an earlier open server
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        for path in (f"/v1/jobs/{record.id}", f"/v1/jobs/{record.id}/result"):
            response = client.get(path, headers={"Authorization": "Bearer key-one"})
            _error(response, 404, "not_found")


def test_an_unfinished_job_on_disk_shows_its_last_saved_state(make_settings) -> None:
    settings = _redis_down(make_settings)
    running = _on_disk(settings, JobState.running, stage="phase2", progress=0.4, eta_s=120.0,
                       started_at=time.time() - 30, worker="worker-1")
    queued = _on_disk(settings, JobState.queued)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        status = client.get(f"/v1/jobs/{running.id}")
        assert status.status_code == 200 and status.headers[STATE_SOURCE_HEADER] == "disk"
        body = status.json()
        assert (body["state"], body["stage"], body["progress"], body["eta_s"]) == (
            "running", "phase2", 0.4, 120.0)
        assert body["finished_at"] is None
        waiting = client.get(f"/v1/jobs/{queued.id}").json()
        assert waiting["state"] == "queued" and waiting["progress"] == 0.0
        assert waiting["stage"] is None and waiting["eta_s"] is None
        _error(client.get(f"/v1/jobs/{running.id}/result"), 409, "not_ready")
        _error(client.get(f"/v1/jobs/{running.id}/artifacts/orbit.mp4"), 409, "not_ready")
        _error(client.delete(f"/v1/jobs/{running.id}"), 503, "store_unavailable")
    assert (settings.data_root / running.id / STATE_FILE).is_file()


def test_without_a_readable_state_file_the_answer_stays_503(make_settings) -> None:
    settings = _redis_down(make_settings)
    damaged = _on_disk(settings, JobState.succeeded)
    (settings.data_root / damaged.id / STATE_FILE).write_text("{not json")
    unknown = str(uuid.uuid4())
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        for job_id in (damaged.id, unknown):
            for suffix in ("", "/result", "/artifacts/orbit.mp4"):
                response = client.get(f"/v1/jobs/{job_id}{suffix}")
                _error(response, 503, "store_unavailable")
                assert int(response.headers["retry-after"]) > 0
                assert STATE_SOURCE_HEADER.lower() not in response.headers
        _error(client.get("/v1/jobs/not-a-job-id"), 404, "not_found")


def test_with_redis_up_the_state_source_header_is_absent(client: TestClient,
                                                         settings: Settings) -> None:
    record = JobRecord(id=str(uuid.uuid4()), state=JobState.succeeded, preset=TINY_PRESET,
                       n_photos=3, created_at=time.time())
    Path(settings.data_root / record.id).mkdir(parents=True)
    JobStore(connect(settings.redis_url), settings.data_root).create(record)
    response = client.get(f"/v1/jobs/{record.id}")
    assert response.status_code == 200 and STATE_SOURCE_HEADER.lower() not in response.headers
