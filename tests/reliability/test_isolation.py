"""Isolation: callers see only their own jobs, ids cannot be guessed, and artifact names cannot
reach outside the job folder (dot segments, encoded dots, absolute paths, symbolic links)."""

from __future__ import annotations

import socket
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.state import JobState, JobStore, connect
from cadnerf_core.jobfolder import JobFolder
from tests.job_results import write_fake_result
from tests.reliability.support import Live, photo_files

KEY_A, KEY_B = "key-alpha-0123456789", "key-bravo-9876543210"
SECRET = "TOP-SECRET-OUTSIDE-THE-JOB"


def _auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


@pytest.fixture()
def keyed(make_settings) -> Iterator[tuple[TestClient, JobStore]]:
    """A client of a service with two API keys, and its job store."""
    settings = make_settings(api_keys=f"{KEY_A}, {KEY_B}")
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client, JobStore(connect(settings.redis_url), settings.data_root)


def _succeed(store: JobStore, job_id: str, outside: Path) -> Path:
    """Give the job the files of a finished job (one of them a link leading out) and succeed it."""
    folder = store.job_dir(job_id)
    (folder / "views").mkdir()
    (folder / "views" / "000.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(16))
    (folder / "poses.json").write_text("{}")
    (folder / "views" / "001.png").symlink_to(outside)
    (folder / "mesh.glb").symlink_to(outside)
    write_fake_result(JobFolder(folder))
    assert store.update(job_id, state=JobState.succeeded, progress=1.0, finished_at=time.time())
    return folder


def test_one_key_cannot_touch_another_keys_jobs(keyed, tmp_path: Path) -> None:
    client, store = keyed
    created = client.post("/v1/jobs", files=photo_files(3), headers=_auth(KEY_A))
    assert created.status_code == 202, created.text
    job_id = created.json()["id"]
    outside = tmp_path / "secret.txt"
    outside.write_text(SECRET)
    _succeed(store, job_id, outside)
    base = f"/v1/jobs/{job_id}"
    for path in (base, f"{base}/result", f"{base}/artifacts/poses.json"):
        assert client.get(path, headers=_auth(KEY_A)).status_code == 200, path
        other = client.get(path, headers=_auth(KEY_B))
        assert other.status_code == 404 and other.json()["error"]["code"] == "not_found", path
        assert client.get(path).status_code == 401, path
        bad = client.get(path, headers=_auth("not-a-key"))
        assert bad.status_code == 401 and bad.headers["www-authenticate"] == "Bearer"
    listing = client.get("/v1/jobs", headers=_auth(KEY_B)).json()
    assert listing["total"] == 0 and listing["items"] == []
    assert [j["id"] for j in client.get("/v1/jobs", headers=_auth(KEY_A)).json()["items"]] == [
        job_id]
    assert client.delete(base, headers=_auth(KEY_B)).status_code == 404
    assert client.delete(base).status_code == 401
    assert client.post("/v1/jobs", files=photo_files(3)).status_code == 401
    assert client.get(base, headers=_auth(KEY_A)).json()["state"] == "succeeded"  # untouched
    assert store.job_dir(job_id).is_dir()
    assert client.delete(base, headers=_auth(KEY_A)).status_code == 200


@pytest.mark.parametrize("name", [
    "../../../../etc/passwd", "..%2f..%2f..%2fetc%2fpasswd", "%2e%2e/%2e%2e/etc/passwd",
    "%2e%2e%2f%2e%2e%2fstate.json", "/etc/passwd", "//etc/passwd", "views/../../state.json",
    "views/001.png", "mesh.glb", "views/%2e%2e/config.json", "state.json", "inputs/000_photo_0.png",
    "views/000.png%00.json", "views\\..\\..\\state.json", "orbit.mp4/..", "views/0000.png",
])
def test_artifact_names_cannot_escape(keyed, tmp_path: Path, name: str) -> None:
    client, store = keyed
    job_id = client.post("/v1/jobs", files=photo_files(3), headers=_auth(KEY_A)).json()["id"]
    outside = tmp_path / "secret.txt"
    outside.write_text(SECRET)
    _succeed(store, job_id, outside)
    response = client.get(f"/v1/jobs/{job_id}/artifacts/{name}", headers=_auth(KEY_A))
    assert response.status_code == 404, (name, response.status_code)
    assert SECRET not in response.text and "root:" not in response.text
    assert response.json()["error"]["message"]
    good = client.get(f"/v1/jobs/{job_id}/artifacts/views/000.png", headers=_auth(KEY_A))
    assert good.status_code == 200


def test_job_ids_are_random_uuid4(client: TestClient) -> None:
    ids = []
    for _ in range(300):
        response = client.post("/v1/jobs", files=photo_files(3, size=(64, 64)))
        assert response.status_code == 202, response.text
        ids.append(response.json()["id"])
    parsed = [uuid.UUID(i) for i in ids]
    assert len(set(ids)) == len(ids)
    assert all(u.version == 4 and str(u) == i for u, i in zip(parsed, ids, strict=True))
    # No order or counter hides in them: consecutive ids share no prefix beyond chance.
    shared = sum(a[:4] == b[:4] for a, b in zip(ids, ids[1:], strict=False))
    assert shared <= 2
    for guess in (str(uuid.uuid4()), ids[0].upper(), ids[0][:-1] + "0", "1", "../" + ids[0]):
        if guess == ids[0][:-1] + "0" and guess in ids:
            continue
        assert client.get(f"/v1/jobs/{guess}").status_code == 404, guess


def _raw_get(live: Live, path: str) -> tuple[int, bytes]:
    port = int(live.url.rsplit(":", 1)[1])
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
        data = b""
        while chunk := sock.recv(65536):
            data += chunk
    status = int(data.split(b" ", 2)[1])
    return status, data


def test_raw_dot_segments_over_a_real_socket(live_api: Live, tmp_path: Path) -> None:
    """Un-normalised paths sent byte for byte (HTTP clients would clean them up first)."""
    import httpx

    created = httpx.post(f"{live_api.url}/v1/jobs", files=photo_files(3), timeout=30)
    job_id = created.json()["id"]
    store = JobStore(connect(live_api.env["CADNERF_REDIS_URL"]), live_api.data_root)
    outside = tmp_path / "secret.txt"
    outside.write_text(SECRET)
    _succeed(store, job_id, outside)
    base = f"/v1/jobs/{job_id}/artifacts"
    for path in (f"{base}/../../../../../etc/passwd", f"{base}/views/../../state.json",
                 f"{base}/./../{job_id}/state.json", "/v1/jobs/../../etc/passwd",
                 f"{base}/views/001.png", f"{base}/mesh.glb"):
        status, data = _raw_get(live_api, path)
        assert status == 404, (path, data[:300])
        assert SECRET.encode() not in data and b"root:" not in data
    assert _raw_get(live_api, f"{base}/views/000.png")[0] == 200
    store.close()
