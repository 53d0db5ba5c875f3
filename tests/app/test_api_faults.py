"""Failures around the API: Redis away, broken or full storage, damaged uploads, odd bodies."""

from __future__ import annotations

import errno
import io
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from app import jobs
from app.embedded import free_port
from app.jobs import TMP_PREFIX
from app.main import create_app


def _error(response, status: int, code: str) -> dict:
    assert response.status_code == status, response.text
    error = response.json()["error"]
    assert error["code"] == code and error["message"]
    return error


def _leftovers(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir()) if root.is_dir() else []


def test_redis_away_gives_503_with_retry_after_and_leaves_no_folder(make_settings,
                                                                    photos) -> None:
    settings = make_settings(redis_url=f"redis://127.0.0.1:{free_port()}/0")
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        for response in (client.get("/v1/jobs"),
                         client.get("/v1/jobs/6f0c3c52-8a3e-4b7e-9d6c-0a1b2c3d4e5f"),
                         client.post("/v1/jobs", files=photos())):
            _error(response, 503, "store_unavailable")
            assert int(response.headers["retry-after"]) > 0
        assert _leftovers(settings.data_root) == []
        assert client.get("/healthz").status_code == 200


def test_a_data_root_that_is_a_file_gives_503(make_settings, photos) -> None:
    settings = make_settings()
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        settings.data_root.rmdir()
        settings.data_root.write_text("not a folder")
        response = client.post("/v1/jobs", files=photos())
        _error(response, 503, "storage_unavailable")
        assert response.headers["retry-after"]


def test_a_full_disk_gives_507_and_removes_the_upload(make_settings, photos,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    settings = make_settings()

    def full(*_: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(jobs, "lay_out", full)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        _error(client.post("/v1/jobs", files=photos()), 507, "storage_full")
        assert not [n for n in _leftovers(settings.data_root) if n.startswith(TMP_PREFIX)]
        assert _leftovers(settings.data_root) == []


def test_a_jpeg_cut_after_its_header_is_refused_by_name(client: TestClient, photos) -> None:
    pixels = np.random.default_rng(0).integers(0, 255, (128, 128, 3), dtype=np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="JPEG", quality=95)
    data = buffer.getvalue()
    files = photos()
    files[1] = ("images", ("cut.jpg", data[: len(data) // 2], "image/jpeg"))
    error = _error(client.post("/v1/jobs", files=files), 422, "unreadable_image")
    assert error["photo"] == "cut.jpg"


def test_an_overlong_multipart_boundary_is_a_400(client: TestClient) -> None:
    boundary = "b" * 300
    response = client.post("/v1/jobs", content=f"--{boundary}--\r\n".encode(), headers={
        "Content-Type": f"multipart/form-data; boundary={boundary}"})
    error = _error(response, 400, "malformed_multipart")
    assert "boundary" in error["message"]
