"""The API with job data in S3-compatible storage (a real ``moto_server``): uploads go to the
store and leave nothing on the API's disk; usage counts the objects; deletion and retention
remove them; a finished job's artifacts are served from the store with ranges and ETags; a
store that cannot be used stops start-up with a message that says which and what to do."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app import jobs
from app.main import create_app
from app.settings import Settings, SettingsError, load_settings
from app.state import JobState
from cadnerf_core.jobfolder import RESULT, JobFolder, StorageError
from tests.job_results import write_fake_result
from tests.s3_fixture import bucket_objects

PREFIX = "deploy/jobs"
Photos = Callable[..., list[tuple[str, tuple[str, bytes, str]]]]


@pytest.fixture()
def s3_settings(make_settings: Callable[..., Settings], s3_bucket: str) -> Settings:
    """Settings storing job data in the test bucket under ``PREFIX``."""
    return make_settings(storage_url=f"s3://{s3_bucket}/{PREFIX}")


@pytest.fixture()
def s3_client_app(s3_settings: Settings) -> Iterator[TestClient]:
    """A client of the app on the object store."""
    with TestClient(create_app(s3_settings)) as test_client:
        yield test_client


def _objects(settings: Settings, bucket: str, job_id: str, endpoint: str) -> dict[str, int]:
    start = f"{PREFIX}/{job_id}/"
    return {k[len(start):]: v for k, v in bucket_objects(endpoint, bucket, start).items()}


def _submit(client: TestClient, photos: Photos) -> str:
    answer = client.post("/v1/jobs", files=photos(3))
    assert answer.status_code == 202, answer.text
    job_id: str = answer.json()["id"]
    return job_id


def test_an_upload_goes_to_the_store_and_leaves_nothing_on_the_api(
        s3_client_app: TestClient, s3_settings: Settings, s3_bucket: str, photos: Photos,
        moto_endpoint: str) -> None:
    job_id = _submit(s3_client_app, photos)
    stored = _objects(s3_settings, s3_bucket, job_id, moto_endpoint)
    assert sorted(n for n in stored if n.startswith("inputs/")) == [
        "inputs/000_photo_0.png", "inputs/001_photo_1.png", "inputs/002_photo_2.png"]
    assert {"config.json", "state.json"} <= set(stored)
    assert not (s3_settings.data_root / job_id).exists()
    usage = s3_client_app.get("/v1/usage").json()
    assert usage["bytes_stored"] == sum(stored.values()) > 0


def test_delete_removes_the_jobs_objects(s3_client_app: TestClient, s3_settings: Settings,
                                         s3_bucket: str, photos: Photos,
                                         moto_endpoint: str) -> None:
    job_id = _submit(s3_client_app, photos)
    assert _objects(s3_settings, s3_bucket, job_id, moto_endpoint)
    assert s3_client_app.delete(f"/v1/jobs/{job_id}").status_code == 200
    assert _objects(s3_settings, s3_bucket, job_id, moto_endpoint) == {}
    assert s3_client_app.get(f"/v1/jobs/{job_id}").status_code == 404


def test_retention_removes_the_objects_of_expired_jobs(
        s3_client_app: TestClient, s3_settings: Settings, s3_bucket: str, photos: Photos,
        moto_endpoint: str) -> None:
    old, fresh = _submit(s3_client_app, photos), _submit(s3_client_app, photos)
    store = s3_client_app.app.state.store  # type: ignore[attr-defined]
    record = store.get(old)
    store.update(old, state=JobState.cancelled, finished_at=record.created_at - 9 * 86400)
    removed = jobs.cleanup(store, retention_s=7 * 86400)
    assert removed == 1
    assert _objects(s3_settings, s3_bucket, old, moto_endpoint) == {}
    assert _objects(s3_settings, s3_bucket, fresh, moto_endpoint)


def _finish_in_store(client: TestClient, job_id: str) -> dict[str, bytes]:
    """Store a finished job's results as a worker would (through the storage), then mark it
    succeeded; returns the bytes written per name."""
    store = client.app.state.store  # type: ignore[attr-defined]
    written = {"poses.json": b'{"model_id": "mug", "photos": []}',
               "orbit.mp4": bytes(range(256)) * 300, "views/000.png": b"\x89PNG fake",
               "results.zip": hashlib.sha256(b"zip").digest() * 2000}
    scratch = store.data_root.parent / "worker-scratch" / job_id
    store.storage.fetch(job_id, scratch)
    for name, data in written.items():
        (scratch / name).parent.mkdir(parents=True, exist_ok=True)
        (scratch / name).write_bytes(data)
    written[RESULT] = write_fake_result(JobFolder(scratch)).model_dump_json(indent=2).encode()
    store.storage.push(job_id, scratch)
    store.storage.release(scratch)
    store.update(job_id, state=JobState.succeeded, finished_at=time.time(), progress=1.0)
    return written


def test_a_finished_jobs_artifacts_are_served_from_the_store(
        s3_client_app: TestClient, photos: Photos) -> None:
    job_id = _submit(s3_client_app, photos)
    written = _finish_in_store(s3_client_app, job_id)
    result = s3_client_app.get(f"/v1/jobs/{job_id}/result")
    assert result.status_code == 200, result.text
    assert result.json() == json.loads(written[RESULT])  # the file, fetched from the store
    assert set(written) <= set(result.json()["artifacts"])
    assert "inputs/000_photo_0.png" not in result.json()["artifacts"]
    base = f"/v1/jobs/{job_id}/artifacts"
    for name, data in written.items():
        assert s3_client_app.get(f"{base}/{name}").content == data, name
    part = s3_client_app.get(f"{base}/orbit.mp4", headers={"Range": "bytes=100-199"})
    assert part.status_code == 206 and part.content == written["orbit.mp4"][100:200]
    etag = s3_client_app.get(f"{base}/results.zip").headers["etag"]
    assert s3_client_app.get(f"{base}/results.zip",
                             headers={"If-None-Match": etag}).status_code == 304


def test_settings_refuse_a_storage_url_that_is_not_s3() -> None:
    with pytest.raises(SettingsError, match="CADNERF_STORAGE_URL.*s3://BUCKET"):
        load_settings(storage_url="http://minio:9000/cadnerf")


def test_a_missing_bucket_stops_start_up_saying_what_to_do(
        make_settings: Callable[..., Settings], s3_env: dict[str, str]) -> None:
    settings = make_settings(storage_url="s3://no-such-bucket-here/jobs")
    with pytest.raises(StorageError) as caught:
        create_app(settings)
    message = str(caught.value)
    assert "s3://no-such-bucket-here/jobs" in message and s3_env["AWS_ENDPOINT_URL"] in message
    assert "does not exist" in message and "create it" in message


def test_an_unreachable_store_stops_the_worker_command_with_a_clear_message(
        tmp_path: Path, redis_url: str, s3_env: dict[str, str]) -> None:
    env: dict[str, Any] = {k: v for k, v in os.environ.items()
                           if not k.startswith(("CADNERF_", "AWS_"))}
    env.update(s3_env, AWS_ENDPOINT_URL="http://127.0.0.1:9", CADNERF_REDIS_URL=redis_url,
               CADNERF_DATA_ROOT=str(tmp_path / "jobs"), CADNERF_STORAGE_URL="s3://jobs-bucket")
    done = subprocess.run([sys.executable, "-m", "cadnerf_cli.main", "worker", "--quiet"],
                          env=env, capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 2, done.stderr[-2000:]
    assert "s3://jobs-bucket" in done.stderr and "cannot be reached" in done.stderr
    assert "AWS_ENDPOINT_URL" in done.stderr
