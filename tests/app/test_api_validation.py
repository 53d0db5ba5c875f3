"""Every rejection at the door: a 4xx JSON error naming the field or photo, and no job folder."""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.settings import Settings
from cadnerf_core.config import resolve_config
from cadnerf_core.jobfolder import JobFolder
from tests.app.images import image_bytes, mask_bytes
from tests.configs import tiny_request, tiny_request_json


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height (no pixel data): a decompression-bomb probe."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    data = zlib.compress(bytes(width * 3 + 1) * 64)  # a few rows; a real bomb has them all
    idat = b"IDAT" + data
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + chunk
            + struct.pack(">I", zlib.crc32(chunk)) + struct.pack(">I", len(data)) + idat
            + struct.pack(">I", zlib.crc32(idat)) + struct.pack(">I", 0) + b"IEND"
            + struct.pack(">I", zlib.crc32(b"IEND")))


def _error(response, status: int, code: str) -> dict:
    assert response.status_code == status, response.text
    error = response.json()["error"]
    assert error["code"] == code and error["message"] and error.get("hint")
    return error


def _assert_no_job_folder(settings: Settings) -> None:
    root = settings.data_root
    assert not root.exists() or list(root.iterdir()) == []


@pytest.mark.parametrize("count", [2, 11])
def test_photo_count(client: TestClient, settings: Settings, photos, count: int) -> None:
    response = client.post("/v1/jobs", files=photos(count))
    code = "photo_count" if count < 3 else "too_many_files"
    assert _error(response, 422, code)["field"] == "images"
    _assert_no_job_folder(settings)


def test_type_is_read_from_content_not_name(client: TestClient, settings: Settings,
                                            photos) -> None:
    files = photos(3)
    files[1] = ("images", ("notes.png", b"just some text, not an image", "image/png"))
    error = _error(client.post("/v1/jobs", files=files), 415, "unsupported_image_type")
    assert error["photo"] == "notes.png"
    files[1] = ("images", ("really_a_jpeg.png", image_bytes((80, 64), "JPEG"), "image/png"))
    job = client.post("/v1/jobs", files=files).json()
    names = sorted(p.name for p in (settings.data_root / job["id"] / "inputs").iterdir())
    assert names[1] == "001_really_a_jpeg.jpg"


def test_webp_and_jpeg_are_accepted(client: TestClient, photos) -> None:
    assert client.post("/v1/jobs", files=photos(3, fmt="WEBP")).status_code == 202
    assert client.post("/v1/jobs", files=photos(3, fmt="JPEG")).status_code == 202


def test_decompression_bomb_is_refused_from_the_header(client: TestClient, settings: Settings,
                                                       photos) -> None:
    files = photos(3)
    files[0] = ("images", ("huge.png", _png_header_only(20000, 20000), "image/png"))
    error = _error(client.post("/v1/jobs", files=files), 422, "image_too_large")
    assert error["photo"] == "huge.png"
    files[0] = ("images", ("big.png", _png_header_only(8000, 6000), "image/png"))  # 48 MP
    assert "megapixels" in _error(client.post("/v1/jobs", files=files), 422,
                                  "image_too_large")["message"]
    _assert_no_job_folder(settings)


def test_small_and_damaged_images(client: TestClient, settings: Settings, photos) -> None:
    files = photos(3)
    files[2] = ("images", ("tiny.png", image_bytes((32, 32)), "image/png"))
    error = _error(client.post("/v1/jobs", files=files), 422, "image_too_small")
    assert error["photo"] == "tiny.png"
    files[2] = ("images", ("cut.png", b"\x89PNG\r\n\x1a\n\x00\x00", "image/png"))
    error = _error(client.post("/v1/jobs", files=files), 422, "unreadable_image")
    assert error["photo"] == "cut.png"
    _assert_no_job_folder(settings)


def test_per_file_limit_is_enforced_while_streaming(make_settings, photos) -> None:
    settings = make_settings(max_file_mb=0.01, max_total_mb=1.0)
    files = photos(3)
    files[1] = ("images", ("noisy.png", image_bytes((80, 64)) + bytes(20000), "image/png"))
    with TestClient(create_app(settings)) as client:
        error = _error(client.post("/v1/jobs", files=files), 413, "file_too_large")
    assert error["photo"] == "noisy.png"
    _assert_no_job_folder(settings)


def test_total_limit_holds_without_content_length(make_settings) -> None:
    """A chunked body (no Content-Length) is still cut off at the limit."""
    settings = make_settings(max_file_mb=0.05, max_total_mb=0.05)
    boundary = "xyz"

    def body() -> Iterator[bytes]:
        for i in range(3):
            yield (f"--{boundary}\r\nContent-Disposition: form-data; name=\"images\"; "
                   f"filename=\"p{i}.png\"\r\nContent-Type: image/png\r\n\r\n").encode()
            yield image_bytes((80, 64)) + bytes(30000) + b"\r\n"
        yield f"--{boundary}--\r\n".encode()

    with TestClient(create_app(settings)) as client:
        response = client.post("/v1/jobs", content=body(),
                               headers={"Content-Type":
                                        f"multipart/form-data; boundary={boundary}"})
    _error(response, 413, "request_too_large")
    _assert_no_job_folder(settings)


def test_declared_content_length_over_the_limit_is_refused(make_settings, photos) -> None:
    settings = make_settings(max_file_mb=0.5, max_total_mb=0.5)
    with TestClient(create_app(settings)) as client:
        response = client.post("/v1/jobs", content=b"x" * 10,
                               headers={"Content-Type": "multipart/form-data; boundary=b",
                                        "Content-Length": str(50 * 2**20)})
    _error(response, 413, "request_too_large")


def test_masks_must_match_photos(client: TestClient, settings: Settings, photos) -> None:
    mask = ("masks", ("m.png", mask_bytes((80, 64)), "image/png"))
    error = _error(client.post("/v1/jobs", files=photos(3) + [mask]), 422, "mask_count")
    assert error["field"] == "masks"
    wrong = ("masks", ("m.png", mask_bytes((64, 80)), "image/png"))
    error = _error(client.post("/v1/jobs", files=photos(3) + [mask, wrong, mask]), 422,
                   "mask_size")
    assert error["photo"] == "photo_1.png" and "64x80" in error["message"]
    _assert_no_job_folder(settings)
    jpeg_mask = ("masks", ("m.jpg", mask_bytes((80, 64), "JPEG"), "image/jpeg"))
    job = client.post("/v1/jobs", files=photos(3) + [mask, jpeg_mask, mask]).json()
    stored = JobFolder(settings.data_root / job["id"]).photos()
    assert all(p.mask is not None and p.mask.read_bytes()[:4] == b"\x89PNG" for p in stored)


@pytest.mark.parametrize(("config", "fragment"), [
    ("{not json", "not valid JSON"),
    (json.dumps({"preset": "turbo"}), "turbo"),
    (tiny_request_json(**{"phase2.steps": -1}), "steps"),
    (tiny_request_json(phase9={"x": 1}), "phase9"),
    (json.dumps({**tiny_request(), "colour": "red"}), "colour"),
    (json.dumps([1, 2]), ""),
])
def test_config_is_validated_by_the_core(client: TestClient, settings: Settings, photos,
                                         config: str, fragment: str) -> None:
    error = _error(client.post("/v1/jobs", files=photos(), data={"config": config}), 422,
                   "invalid_config")
    assert error["field"] == "config" and fragment in error["message"]
    _assert_no_job_folder(settings)


@pytest.mark.parametrize(("overrides", "name"), [
    ({"phase2": {"prior_weight": 1.0}}, "phase2.prior_weight"),  # deleted
    ({"retrieval.hypotheses": 3}, "retrieval.hypotheses"),  # the preset's own
    ({"field": {"hidden": 8}}, "field.hidden"),  # a section a client may not touch
])
def test_a_setting_a_client_may_not_send_answers_422_naming_it(
        client: TestClient, settings: Settings, photos, overrides: dict[str, object],
        name: str) -> None:
    config = json.dumps({"preset": "preview", "overrides": overrides})
    error = _error(client.post("/v1/jobs", files=photos(), data={"config": config}), 422,
                   "invalid_config")
    assert error["field"] == "config"
    assert error["message"].startswith(f"{name}: not a setting a client may send"), error
    _assert_no_job_folder(settings)


def test_openapi_types_the_config_field_by_the_client_settings(client: TestClient) -> None:
    from cadnerf_core.config_client import CLIENT_SETTINGS, client_schema

    body = client.get("/openapi.json").json()["paths"]["/v1/jobs"]["post"]["requestBody"]
    form = body["content"]["multipart/form-data"]
    assert form["encoding"]["config"]["contentType"] == "application/json"
    config = form["schema"]["properties"]["config"]
    assert config["properties"]["overrides"]["properties"] == client_schema()["properties"]
    assert "$ref" not in json.dumps(config) and len(CLIENT_SETTINGS) <= 30


def test_overrides_are_kept_with_the_job(client: TestClient, settings: Settings, photos) -> None:
    config = {"preset": "preview", "overrides": {"phase2.steps": 3}}
    job = client.post("/v1/jobs", files=photos(), data={"config": json.dumps(config)}).json()
    resolved = JobFolder(settings.data_root / job["id"]).read_config()
    assert resolved == resolve_config("preview", {"phase2.steps": 3})


def test_other_form_problems(client: TestClient, settings: Settings, photos) -> None:
    error = _error(client.post("/v1/jobs", files=photos(), data={"webhook_url": "ftp://x"}),
                   422, "invalid_webhook_url")
    assert error["field"] == "webhook_url"
    assert _error(client.post("/v1/jobs", files=photos(), data={"colour": "red"}), 422,
                  "unknown_field")["field"] == "colour"
    files = photos() + [("config", ("c.json", b"{}", "application/json"))]
    error = _error(client.post("/v1/jobs", files=files), 422, "wrong_field_type")
    assert error["field"] == "config"
    _error(client.post("/v1/jobs", json={"images": []}), 415, "unsupported_media_type")
    _error(client.post("/v1/jobs", content=b"--b\r\nno colon here\r\n\r\nx\r\n--b--\r\n",
                       headers={"Content-Type": "multipart/form-data; boundary=b"}),
           400, "malformed_multipart")
    _error(client.post("/v1/jobs", content=b"--b\r\ngarbage",
                       headers={"Content-Type": "multipart/form-data; boundary=b"}),
           422, "photo_count")
    _assert_no_job_folder(settings)


def test_client_file_names_never_become_paths(client: TestClient, settings: Settings,
                                              photos) -> None:
    files = photos(3)
    files[0] = ("images", ("../../../evil.png", image_bytes((80, 64)), "image/png"))
    files[1] = ("images", ("..\\..\\x y\u202e.png", image_bytes((80, 64)), "image/png"))
    files[2] = ("images", ("....png", image_bytes((80, 64)), "image/png"))
    job = client.post("/v1/jobs", files=files).json()
    folder = settings.data_root / job["id"]
    assert sorted(p.name for p in (folder / "inputs").iterdir()) == [
        "000_evil.png", "001_x_y.png", "002_png.png"]
    assert sorted(p.name for p in settings.data_root.parent.iterdir()) == ["jobs", "library"]
    assert all(Path(p).resolve().is_relative_to(folder) for p in (folder / "inputs").iterdir())
