"""Bad-input battery: every hostile or broken upload gets a 4xx JSON error naming what is wrong,
the service keeps answering, nothing is written outside the job root and no half job is left."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from tests.configs import tiny_request_json
from tests.reliability.cases import CASES, with_photo
from tests.reliability.support import (
    Live,
    image_bytes,
    multipart_body,
    new_paths,
    noisy_jpeg,
    photo_files,
    send_truncated_upload,
    tree,
    wait_for,
)


def _error(response: httpx.Response, status: int, code: str) -> dict[str, str]:
    assert response.status_code == status, response.text[:500]
    assert response.headers["content-type"].startswith("application/json")
    error = response.json()["error"]
    assert error["code"] == code, error
    assert error["message"] and error["hint"], error
    return dict(error)


@pytest.mark.parametrize("name", sorted(CASES))
def test_each_bad_upload_is_refused_clearly(client: TestClient, sandbox: Path,
                                            name: str) -> None:
    case = CASES[name]()
    before = tree(sandbox)
    response = client.post("/v1/jobs", files=case.files, data=case.texts)
    error = _error(response, case.status, case.code)
    pointed = " ".join(str(error.get(k) or "") for k in ("photo", "field", "message"))
    assert case.names in pointed, error
    assert len(json.dumps(error)) < 2000  # a 3000-character name is not echoed in full
    assert new_paths(before, tree(sandbox)) == set(), "a rejected upload left files behind"
    assert client.get("/healthz").json() == {"status": "ok"}


def test_size_limit_names_the_photo(make_settings, sandbox: Path) -> None:
    settings = make_settings(max_file_mb=0.02, max_total_mb=1.0)
    big = image_bytes((80, 64)) + bytes(40_000)
    files = with_photo(1, ("images", ("big.png", big, "image/png")))
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        before = tree(sandbox)
        error = _error(client.post("/v1/jobs", files=files), 413, "file_too_large")
        assert error["photo"] == "big.png" and error["field"] == "images"
        assert new_paths(before, tree(sandbox)) == set()


@pytest.mark.parametrize(("content_type", "body", "status"), [
    ("application/json", b'{"images": []}', 415),
    ("text/plain", b"hello", 415),
    ("multipart/form-data", b"--x--\r\n", 415),  # no boundary
    ("multipart/mixed; boundary=x", b"--x--\r\n", 415),
    ("multipart/form-data; boundary=" + "b" * 3000, b"--b--\r\n", 400),
    ("image/jpeg", noisy_jpeg((64, 64)), 415),
])
def test_wrong_content_types(client: TestClient, sandbox: Path, content_type: str, body: bytes,
                             status: int) -> None:
    before = tree(sandbox)
    response = client.post("/v1/jobs", content=body, headers={"Content-Type": content_type})
    assert 400 <= response.status_code < 500, response.text[:300]
    assert response.json()["error"]["message"]
    assert new_paths(before, tree(sandbox)) == set()


@pytest.mark.parametrize("filename", [
    "../../../../tmp/evil.png", "/etc/passwd", "..\\..\\win.png", "nul\x00byte.png",
    "x" * 3000 + ".png", "%2e%2e%2f%2e%2e%2fescape.png", "\u202eevil\u0000.png", ".",
])
def test_hostile_file_names_stay_inside_the_job(client: TestClient, sandbox: Path,
                                                filename: str) -> None:
    files = with_photo(0, ("images", (filename, image_bytes((80, 64)), "image/png")))
    body = multipart_body(files)
    before = tree(sandbox)
    response = client.post("/v1/jobs", content=body, headers={
        "Content-Type": "multipart/form-data; boundary=reliability-boundary"})
    assert response.status_code == 202, response.text[:300]
    job_id = response.json()["id"]
    added = new_paths(before, tree(sandbox))
    assert added and all(p.startswith(f"jobs/{job_id}") for p in added), added
    stored = sorted(p.name for p in (sandbox / "jobs" / job_id / "inputs").iterdir())
    assert len(stored) == 3 and all(len(s) <= 60 and s.isascii() for s in stored), stored
    assert all("/" not in s and "\x00" not in s and ".." not in s for s in stored)


def test_upload_cut_off_mid_body_leaves_nothing(live_api: Live) -> None:
    sandbox = live_api.folder
    before = tree(sandbox)
    port = int(live_api.url.rsplit(":", 1)[1])
    body = multipart_body(photo_files(3, size=(256, 256)), {"config": tiny_request_json()})
    for fraction in (0.1, 0.5, 0.95):
        send_truncated_upload(port, body, fraction)
    jobs_root = live_api.data_root

    def settled() -> bool:  # the staging folders are removed once the server sees the close
        return not any(p.name.startswith(".upload-") for p in jobs_root.iterdir())

    assert wait_for(settled, 60), \
        f"staging folders stayed: {sorted(p.name for p in jobs_root.iterdir())}"
    added = {p for p in new_paths(before, tree(sandbox)) if not p.endswith(".log")}
    assert added == set(), added
    assert httpx.get(f"{live_api.url}/healthz", timeout=5).status_code == 200
    # The server still accepts a whole upload afterwards.
    done = httpx.post(f"{live_api.url}/v1/jobs", files=photo_files(3), timeout=30)
    assert done.status_code == 202, done.text


def test_server_survives_the_battery_over_http(live_api: Live) -> None:
    """The whole battery against the real uvicorn process: never a 5xx, never a crash."""
    wrong = {}
    with httpx.Client(base_url=live_api.url, timeout=60) as http:
        for name in sorted(CASES):
            case = CASES[name]()
            response = http.post("/v1/jobs", files=case.files, data=case.texts)
            if response.status_code != case.status:
                wrong[name] = (response.status_code, response.text[:200])
        assert http.get("/healthz").status_code == 200
    assert live_api.api.popen.poll() is None, live_api.api.tail()
    assert wrong == {}
