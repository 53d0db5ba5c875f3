"""Redis going away and storage that cannot be written: the API answers 503 with a Retry-After
hint (not 500), jobs come back from state.json, a full or broken job root gives a clear error."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import redis
from fastapi.testclient import TestClient

from app.main import create_app
from app.settings import Settings, load_settings
from tests.configs import TINY_PRESET, tiny_request
from tests.reliability import jobs
from tests.reliability.support import (
    NEEDS_PIPELINE,
    Proc,
    free_port,
    photo_files,
    pipeline_ready,
    render_photo_set,
    start_live,
    start_redis,
    stop_live,
    tree,
    wait_for,
)

_restarted: list[Proc] = []  # the redis-server processes of the running test
HANG_S = 120.0  # a wait that only guards against a hang, never a measure


@pytest.fixture()
def own_redis(tmp_path: Path) -> Iterator[tuple[str, int, Path]]:
    """A redis-server of this test's own (never the shared one): URL, port, data folder.

    Persistence is off, so a restart comes back empty, as a lost Redis would.
    """
    port = free_port()
    folder = tmp_path / "redis"
    _restarted.append(start_redis(folder, port))
    yield f"redis://127.0.0.1:{port}/0", port, folder
    for proc in _restarted:
        proc.stop()
    _restarted.clear()


def _kill_redis(port: int) -> None:
    client = redis.Redis(port=port, socket_connect_timeout=1)
    with contextlib.suppress(redis.RedisError):
        client.shutdown(nosave=True)
    client.close()
    wait_for(lambda: not _answers(port), 10, 0.1)


def _answers(port: int) -> bool:
    try:
        return bool(redis.Redis(port=port, socket_connect_timeout=0.3).ping())
    except redis.RedisError:
        return False


def _restart_redis(folder: Path, port: int) -> None:
    _restarted.append(start_redis(folder, port))


def _assert_unavailable(response: httpx.Response) -> None:
    assert response.status_code == 503, (response.status_code, response.text[:300])
    assert int(response.headers["retry-after"]) > 0
    error = response.json()["error"]
    assert error["message"] and error["code"]


def _settings(redis_url: str, tmp_path: Path) -> Settings:
    """API settings on the test's own Redis, with jobs and library under ``tmp_path``."""
    return load_settings(redis_url=redis_url, data_root=tmp_path / "jobs",
                         library_dir=tmp_path / "library", default_preset=TINY_PRESET)


def test_redis_down_gives_503_with_retry_after(own_redis: tuple[str, int, Path],
                                               tmp_path: Path) -> None:
    url, port, _folder = own_redis
    settings = _settings(url, tmp_path)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        job_id = client.post("/v1/jobs", files=photo_files(3)).json()["id"]
        _kill_redis(port)
        before = tree(tmp_path / "jobs")
        assert client.get("/healthz").status_code == 200
        assert client.get("/readyz").status_code == 503
        status = client.get(f"/v1/jobs/{job_id}")  # its state.json answers (reliability.md)
        assert status.status_code == 200 and status.json()["state"] == "queued"
        assert status.headers["x-job-state-source"] == "disk"
        _assert_unavailable(client.get(f"/v1/jobs/{uuid.uuid4()}"))  # no state.json: unknown
        _assert_unavailable(client.get("/v1/jobs"))
        _assert_unavailable(client.delete(f"/v1/jobs/{job_id}"))
        _assert_unavailable(client.post("/v1/jobs", files=photo_files(3)))
        assert tree(tmp_path / "jobs") == before, "a refused upload left a job folder"


def test_jobs_come_back_from_state_json_after_redis_restart(own_redis: tuple[str, int, Path],
                                                            tmp_path: Path) -> None:
    url, port, folder = own_redis
    settings = _settings(url, tmp_path)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        ids = [client.post("/v1/jobs", files=photo_files(3)).json()["id"] for _ in range(3)]
        _kill_redis(port)
        assert client.get(f"/v1/jobs/{ids[0]}").headers["x-job-state-source"] == "disk"
        _restart_redis(folder, port)

        def from_redis() -> bool:
            response = client.get(f"/v1/jobs/{ids[0]}")
            return response.status_code == 200 and "x-job-state-source" not in response.headers

        assert wait_for(from_redis, HANG_S, 0.1), "the jobs were not read from Redis again"
        for job_id in ids:
            status = client.get(f"/v1/jobs/{job_id}").json()
            assert status["state"] == "queued" and status["n_photos"] == 3, status
        listed = [j["id"] for j in client.get("/v1/jobs").json()["items"]]
        assert listed == ids[::-1]  # newest first, as before the restart


def test_data_root_replaced_by_a_file_gives_a_clear_error(make_settings, sandbox: Path) -> None:
    settings = make_settings()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        root = settings.data_root
        os.rmdir(root)
        root.write_text("not a folder")  # the storage went away under the running API
        response = client.post("/v1/jobs", files=photo_files(3))
        assert response.status_code in (503, 507), (response.status_code, response.text[:300])
        assert response.json()["error"]["message"]
        assert client.get("/healthz").status_code == 200


def _mount_tmpfs(path: Path, size: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, timeout=10, check=False)
    return done.returncode == 0


def test_full_disk_gives_a_clear_error_and_leaves_nothing(make_settings, tmp_path: Path) -> None:
    mount = tmp_path / "small"
    if not _mount_tmpfs(mount, "256k"):
        pytest.skip("no permission to mount a tmpfs here")
    try:
        settings = make_settings(data_root=mount / "jobs")
        with TestClient(create_app(settings), raise_server_exceptions=False) as client:
            (mount / "filler").write_bytes(bytes(200 * 1024))
            files = photo_files(3, size=(300, 300), fmt="PNG")
            files[1] = ("images", ("big.png", _noise_png(), "image/png"))
            response = client.post("/v1/jobs", files=files)
            assert response.status_code in (503, 507), (response.status_code, response.text)
            assert response.json()["error"]["message"]
            assert sorted(p.name for p in (mount / "jobs").iterdir()) == []
            assert client.get("/healthz").status_code == 200
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True, timeout=10,
                       check=False)


def _noise_png() -> bytes:
    import io

    import numpy as np
    from PIL import Image

    pixels = np.random.default_rng(1).integers(0, 255, (200, 200, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.mark.slow
@pytest.mark.skipif(not pipeline_ready(), reason=NEEDS_PIPELINE)
def test_redis_restart_during_a_job(own_redis: tuple[str, int, Path], tiny_library_dir: Path,
                                    tmp_path: Path) -> None:
    """Redis vanishes (and comes back empty) while a job trains: the job is found again from
    state.json and does not stay `running` for ever."""
    url, port, folder = own_redis
    live = start_live(tmp_path / "service", url, tiny_library_dir)
    try:
        photos = render_photo_set(tmp_path / "photos")
        job = jobs.submit(live.url, photos, tiny_request(phase3={"steps": 4000}))
        jobs.wait_state(live.url, job["id"], 240, until=("running",), stage="phase3")
        _kill_redis(port)
        # while down, the status is read from state.json: the last mirrored state, marked
        down = httpx.get(f"{live.url}/v1/jobs/{job['id']}", timeout=10)
        assert down.status_code == 200 and down.headers["x-job-state-source"] == "disk"
        # The job may finish in the moments Redis is down (a few seconds of phase three are
        # left on a fast machine): the disk copy then says so. Either way it is a live state.
        assert down.json()["state"] in ("running", "succeeded"), down.text
        assert down.json()["stage"] == "phase3", down.text
        time.sleep(2)
        _restart_redis(folder, port)

        def from_redis() -> bool:
            response = httpx.get(f"{live.url}/v1/jobs/{job['id']}", timeout=5)
            return response.status_code == 200 and "x-job-state-source" not in response.headers

        assert wait_for(from_redis, HANG_S), \
            f"the job was not read from Redis again\n{live.logs()}"
        # The rest of the job takes seconds; the wait only guards against a job left `running`
        # for ever, the failure this test is about.
        try:
            final, _ = jobs.wait_state(live.url, job["id"], 5 * HANG_S)
        except AssertionError as exc:
            raise AssertionError(f"the job never ended after Redis came back: {exc}\n"
                                 f"{live.logs()}") from None
        assert final["state"] in ("succeeded", "failed"), final
        if final["state"] == "failed":
            assert final["error"], final
    finally:
        if live.worker is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(live.worker.pid, signal.SIGTERM)
        stop_live(live)
