"""Job routes against a real Redis: submit, poll, list, result, artifacts, delete."""

from __future__ import annotations

import io
import json
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import redis
from fastapi.testclient import TestClient
from PIL import Image

from app import jobs
from app.settings import Settings
from app.state import JobState, JobStore, connect, keys
from cadnerf_core.jobfolder import JobFolder, MaskSource
from tests.configs import TINY_PRESET, tiny_config, tiny_request_json
from tests.job_results import write_fake_result


def _store(settings: Settings) -> JobStore:
    return JobStore(connect(settings.redis_url), settings.data_root)


def _submit(client: TestClient, photos, **data: str) -> dict:
    response = client.post("/v1/jobs", files=photos(), data=data)
    assert response.status_code == 202, response.text
    return response.json()


@dataclass
class _Found:
    mask: np.ndarray
    source: MaskSource
    warnings: list[str]


def _succeed(settings: Settings, job_id: str) -> Path:
    """Write what the pipeline writes into the job folder and mark the job succeeded."""
    job = JobFolder(settings.data_root / job_id)
    folder = job.root
    (folder / "views").mkdir()
    (folder / "orbit.mp4").write_bytes(bytes(range(256)) * 8)
    (folder / "mesh.glb").write_bytes(b"glTF" + bytes(60))
    Image.new("RGB", (32, 32), "gray").save(job.view_path(0))
    photos = job.photos()
    found = [_Found(np.ones((64, 80), bool), source, [])
             for source in ("uploaded", "alpha", "learned")]
    found[2].warnings.append(f"{photos[2].name}: the mask touches three borders (crop or retake)")
    job.write_masks(photos, found, (np.full((64, 80, 3), 90, np.uint8) for _ in photos))
    write_fake_result(job, discarded=(2,))
    store = _store(settings)
    assert store.update(job_id, state=JobState.succeeded, progress=1.0, finished_at=time.time())
    store.mirror(job_id)
    return folder


def test_submit_stores_the_job_and_queues_it_by_name(client: TestClient, settings: Settings,
                                                     photos, clean_redis: redis.Redis) -> None:
    response = client.post("/v1/jobs", files=photos(3),
                           data={"config": tiny_request_json()})
    assert response.status_code == 202
    body = response.json()
    assert uuid.UUID(body["id"]).version == 4
    assert response.headers["location"] == f"/v1/jobs/{body['id']}"
    assert body["state"] == "queued" and body["n_photos"] == 3 and body["preset"] == TINY_PRESET
    folder = settings.data_root / body["id"]
    assert sorted(p.name for p in (folder / "inputs").iterdir()) == [
        "000_photo_0.png", "001_photo_1.png", "002_photo_2.png"]
    assert JobFolder(folder).read_config() == tiny_config()
    assert json.loads((folder / "state.json").read_text())["state"] == "queued"
    messages = clean_redis.lrange("cadnerf", 0, -1)
    assert len(messages) == 1
    headers = json.loads(messages[0])["headers"]
    assert headers["task"] == "cadnerf.run_job" and body["id"] in headers["argsrepr"]
    assert [p.name for p in settings.data_root.iterdir()] == [body["id"]]  # no staging left


def test_status_is_read_back_and_unknown_ids_are_404(client: TestClient, photos) -> None:
    job = _submit(client, photos)
    status = client.get(f"/v1/jobs/{job['id']}").json()
    assert status["id"] == job["id"] and status["state"] == "queued" and status["progress"] == 0
    for bad in (str(uuid.uuid4()), "not-an-id", "..%2F..%2Fetc"):
        response = client.get(f"/v1/jobs/{bad}")
        assert response.status_code == 404
        assert response.json()["error"]["code"] == "not_found"


def test_status_survives_a_redis_flush_through_state_json(client: TestClient, photos,
                                                          clean_redis: redis.Redis) -> None:
    job = _submit(client, photos)
    clean_redis.flushdb()
    response = client.get(f"/v1/jobs/{job['id']}")
    assert response.status_code == 200 and response.json()["state"] == "queued"
    assert clean_redis.hget(keys.job(job["id"]), "state") == "queued"  # re-seeded
    assert [j["id"] for j in client.get("/v1/jobs").json()["items"]] == [job["id"]]


def test_list_is_newest_first_and_paginated(client: TestClient, photos) -> None:
    ids = [_submit(client, photos)["id"] for _ in range(3)]
    page = client.get("/v1/jobs", params={"limit": 2}).json()
    assert [j["id"] for j in page["items"]] == ids[::-1][:2]
    assert page["total"] == 3 and page["next"] == "/v1/jobs?limit=2&offset=2"
    last = client.get(page["next"]).json()
    assert [j["id"] for j in last["items"]] == [ids[0]] and last["next"] is None
    assert client.get("/v1/jobs", params={"limit": 0}).status_code == 422


def test_result_is_409_until_succeeded_then_the_file_the_pipeline_wrote(
        client: TestClient, settings: Settings, photos) -> None:
    job = _submit(client, photos)
    early = client.get(f"/v1/jobs/{job['id']}/result")
    assert early.status_code == 409 and early.json()["error"]["code"] == "not_ready"
    assert client.get(f"/v1/jobs/{job['id']}/artifacts/orbit.mp4").status_code == 409
    folder = JobFolder(_succeed(settings, job["id"]))
    response = client.get(f"/v1/jobs/{job['id']}/result")
    assert response.status_code == 200, response.text
    result = response.json()
    assert result == json.loads(folder.file("result.json").read_text())
    assert result["model"] == {"id": "chair_01", "category": "chair", "perspective": "far"}
    assert result["discarded"] == ["002_photo_2.png"]
    assert result["photos"][2]["c2w"] is None and result["photos"][0]["K"][0][0] == 50
    assert [p["mask_source"] for p in result["photos"]] == ["uploaded", "alpha", "learned"]
    assert "photo_2.png" in result["warnings"][0]
    for name in ("orbit.mp4", "views/000.png", "masks/001_overlay.jpg", "result.json"):
        assert name in result["artifacts"], name
        assert client.get(f"/v1/jobs/{job['id']}/artifacts/{name}").status_code == 200, name
    overlay = client.get(f"/v1/jobs/{job['id']}/artifacts/{result['photos'][1]['overlay']}")
    assert overlay.status_code == 200 and overlay.headers["content-type"] == "image/jpeg"
    assert "attachment" not in overlay.headers.get("content-disposition", "")
    assert Image.open(io.BytesIO(overlay.content)).size == (80, 64)
    # Served as written: what the folder says is what the API says, nothing merged on top.
    write_fake_result(folder, warnings=["written by the pipeline"], reordered=True)
    again = client.get(f"/v1/jobs/{job['id']}/result").json()
    assert again["warnings"] == ["written by the pipeline"] and again["reordered"]


def test_a_succeeded_job_without_a_readable_result_is_404_not_500(
        client: TestClient, settings: Settings, photos) -> None:
    job = _submit(client, photos)
    folder = JobFolder(_succeed(settings, job["id"]))
    folder.file("result.json").write_text('{"model": {"id": "x"}, "photos": "not a list"}')
    response = client.get(f"/v1/jobs/{job['id']}/result")
    assert response.status_code == 404 and response.json()["error"]["code"] == "no_result"
    folder.file("result.json").unlink()
    assert client.get(f"/v1/jobs/{job['id']}/result").status_code == 404


def test_library_silhouettes_are_served_as_png_for_listed_models_only(
        client: TestClient, settings: Settings) -> None:
    from cadnerf_core.library.format import pack_silhouettes, save_npz

    masks = np.zeros((4, 16, 16), bool)
    masks[2, 4:12, 6:10] = True
    near = np.zeros((4, 16, 16), bool)
    near[2, :8] = True
    (settings.library_dir / "chair_01").mkdir()
    save_npz(settings.library_dir / "chair_01" / "silhouettes.npz",
             pack_silhouettes(masks, np.zeros((4, 3)), (near, np.zeros((4, 3)))))
    response = client.get("/v1/library/chair_01/silhouette/2")
    assert response.status_code == 200 and response.headers["content-type"] == "image/png"
    assert "max-age" in response.headers["cache-control"]
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(response.content))) > 127, masks[2])
    near_png = client.get("/v1/library/chair_01/silhouette/2", params={"perspective": "near"})
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(near_png.content))) > 127, near[2])
    for path in ("chair_01/silhouette/4", "cuboid_1x1x1/silhouette/0", "nope/silhouette/0",
                 "..%2Fchair_01/silhouette/0", "chair_01/silhouette/-1"):
        response = client.get(f"/v1/library/{path}")
        assert response.status_code in (404, 422), path
        assert response.status_code == 422 or response.json()["error"]["code"] in (
            "no_such_model", "no_such_view", "not_found"), path


def test_artifacts_stream_with_ranges_and_stay_inside_the_job(client: TestClient,
                                                               settings: Settings, photos) -> None:
    job = _submit(client, photos)
    folder = _succeed(settings, job["id"])
    base = f"/v1/jobs/{job['id']}/artifacts"
    whole = client.get(f"{base}/orbit.mp4")
    assert whole.status_code == 200 and whole.headers["content-type"] == "video/mp4"
    assert whole.headers["accept-ranges"] == "bytes"
    part = client.get(f"{base}/orbit.mp4", headers={"Range": "bytes=10-19"})
    assert part.status_code == 206 and part.content == bytes(range(10, 20))
    assert part.headers["content-range"] == "bytes 10-19/2048"
    assert client.get(f"{base}/mesh.glb").headers["content-type"] == "model/gltf-binary"
    assert client.get(f"{base}/views/000.png").headers["content-type"] == "image/png"
    (folder / "views" / "001.png").symlink_to("/etc/hostname")
    for name in ("state.json", "../state.json", "views/../../x", "views/001.png",
                 "inputs/000_photo_0.png", "orbit.avi", "inputs/masks/000_photo_0.png",
                 "masks/../inputs/000_photo_0.png", "masks/003.png"):
        response = client.get(f"{base}/{name}")
        assert response.status_code == 404, name


def test_delete_cancels_a_queued_job_and_removes_everything(client: TestClient,
                                                            settings: Settings, photos,
                                                            clean_redis: redis.Redis) -> None:
    job = _submit(client, photos)
    response = client.delete(f"/v1/jobs/{job['id']}")
    assert response.status_code == 200
    assert response.json() == {"id": job["id"], "deleted": True, "previous_state": "queued",
                               "worker_stopped": True}
    assert not (settings.data_root / job["id"]).exists()
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404
    assert clean_redis.exists(keys.job(job["id"])) == 0
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 404


def test_delete_of_a_running_job_waits_for_the_worker(settings: Settings) -> None:
    """DELETE returns after the worker ended the job, not before: the order of the events,
    never the time taken (the wait is a hang guard)."""
    store = _store(settings)
    record = _record(settings, state=JobState.running)
    ended = threading.Event()

    def worker() -> None:  # stops at its next step once it sees the cancel flag
        own = _store(settings)
        try:
            while not own.cancel_requested(record.id):
                time.sleep(0.01)
            own.update(record.id, state=JobState.cancelled, finished_at=time.time())
            ended.set()
        finally:
            own.close()

    thread = threading.Thread(target=worker, daemon=True)
    thread.start()
    result = jobs.delete_job(store, record, wait_s=60)
    assert ended.is_set(), "DELETE returned before the worker ended the job"
    assert result.worker_stopped is True and result.previous_state == JobState.running
    assert store.get(record.id) is None
    thread.join(60)

    silent = _record(settings, state=JobState.running)  # no worker acknowledges
    result = jobs.delete_job(store, silent, wait_s=0.5)
    assert result.worker_stopped is False
    assert store.get(silent.id) is None and not (settings.data_root / silent.id).exists()


def _record(settings: Settings, state: JobState = JobState.queued, created_at: float | None = None,
            finished_at: float | None = None):
    from app.state import JobRecord

    record = JobRecord(id=str(uuid.uuid4()), preset=TINY_PRESET, n_photos=3, state=state,
                       created_at=created_at or time.time(), finished_at=finished_at)
    (settings.data_root / record.id).mkdir(parents=True)
    _store(settings).create(record)
    return record


def test_cleanup_removes_expired_jobs_and_stale_uploads(settings: Settings) -> None:
    store = _store(settings)
    day = 86400.0
    old = _record(settings, JobState.succeeded, time.time() - 10 * day, time.time() - 9 * day)
    fresh = _record(settings, JobState.succeeded, time.time() - day, time.time() - day)
    running = _record(settings, JobState.running, time.time() - 10 * day)
    staging = settings.data_root / ".upload-abandoned"
    staging.mkdir()
    removed = jobs.cleanup(store, retention_s=7 * day, now=time.time() + 2 * 3600)
    assert removed == 1
    assert store.get(old.id) is None and not (settings.data_root / old.id).exists()
    assert store.get(fresh.id) is not None and store.get(running.id) is not None
    assert not staging.exists()
