"""API keys, library, info, health, readiness, the page and the API description."""

from __future__ import annotations

import json
import re

import redis
from fastapi.testclient import TestClient

from app.main import create_app
from app.routes.pages import STATIC_DIR
from app.state import Workers
from tests.configs import TINY_PRESET


def test_api_keys_guard_every_v1_route_and_separate_owners(make_settings, photos) -> None:
    settings = make_settings(api_keys="key-one, key-two")
    one = {"Authorization": "Bearer key-one"}
    two = {"Authorization": "Bearer key-two"}
    with TestClient(create_app(settings)) as client:
        for method, path in (("get", "/v1/jobs"), ("get", "/v1/library"), ("get", "/v1/info"),
                             ("post", "/v1/jobs")):
            response = getattr(client, method)(path)
            assert response.status_code == 401, path
            assert response.headers["www-authenticate"] == "Bearer"
            assert response.json()["error"]["code"] == "unauthorized"
        bad = client.get("/v1/jobs", headers={"Authorization": "Bearer nope"})
        assert bad.status_code == 401 and "not valid" in bad.json()["error"]["message"]
        job = client.post("/v1/jobs", files=photos(), headers=one).json()
        assert client.get(f"/v1/jobs/{job['id']}", headers=one).status_code == 200
        assert client.get(f"/v1/jobs/{job['id']}", headers=two).status_code == 404
        assert client.delete(f"/v1/jobs/{job['id']}", headers=two).status_code == 404
        assert client.get("/v1/jobs", headers=two).json()["total"] == 0
        assert client.get("/v1/jobs", headers=one).json()["total"] == 1
        assert client.get("/healthz").status_code == 200  # liveness stays open
    state = json.loads((settings.data_root / job["id"] / "state.json").read_text())
    assert len(state["owner"]) == 64 and "key-one" not in json.dumps(state)


def test_library_lists_manifest_models(client: TestClient, make_settings) -> None:
    body = client.get("/v1/library").json()
    assert [m["id"] for m in body["models"]] == ["chair_01", "cuboid_1x1x1"]
    assert body["models"][0]["category"] == "chair" and body["n_views"] == 100
    missing = make_settings(library_dir="/nonexistent/library")
    with TestClient(create_app(missing)) as other:
        response = other.get("/v1/library")
    assert response.status_code == 503 and response.json()["error"]["code"] == "library_missing"


def test_info_tells_presets_and_limits(client: TestClient) -> None:
    info = client.get("/v1/info").json()
    assert {"preview", "standard", "paper"} <= set(info["presets"])
    assert info["default_preset"] == TINY_PRESET
    assert info["min_photos"] == 3 and info["max_photos"] == 10


def test_readiness_needs_redis_and_a_worker_heartbeat(client: TestClient,
                                                      clean_redis: redis.Redis) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    not_ready = client.get("/readyz")
    assert not_ready.status_code == 503 and not_ready.json()["redis"] is True
    Workers(clean_redis).beat("host-1", 5, {"pid": 1})
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["workers"] == ["host-1"]


def test_readiness_reports_a_dead_redis(make_settings) -> None:
    settings = make_settings(redis_url="redis://127.0.0.1:1/0")
    with TestClient(create_app(settings)) as client:
        response = client.get("/readyz")
        assert response.status_code == 503 and response.json()["redis"] is False
        assert client.get("/healthz").status_code == 200


def test_the_page_and_its_assets_are_served(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    for needle in ('id="photos"', 'id="orbit"', "autoplay", 'id="cameras"',
                   '<script type="module" src="/static/main.js">'):
        assert needle in page.text
    # Browsers run a module only when it is served as JavaScript: follow main.js's imports.
    scripts: dict[str, str] = {}
    pending = ["main.js"]
    while pending:
        name = pending.pop()
        if name in scripts:
            continue
        script = client.get(f"/static/{name}")
        assert script.status_code == 200, name
        assert script.headers["content-type"].startswith("text/javascript"), name
        assert script.headers["cache-control"] == "no-cache", name  # revalidated: no mixed versions
        scripts[name] = script.text
        pending += re.findall(r'^import .* from "\./([\w-]+\.js)";$', script.text, re.M)
    assert set(scripts) == {path.name for path in STATIC_DIR.glob("*.js")}  # none left out
    assert any("/v1/jobs" in text for text in scripts.values())
    assert client.get("/static/style.css").status_code == 200
    assert client.get("/static/../schemas.py").status_code == 404


def test_every_resource_the_page_names_is_served_or_inline(client: TestClient) -> None:
    # A browser asks for /favicon.ico unless the page declares its icon; the server serves no
    # such file, so an undeclared icon is a 404 on every visit.
    page = client.get("/").text
    assert re.search(r'<link rel="icon" href="data:image/svg\+xml,', page)
    for url in re.findall(r'(?:href|src)="([^"]+)"', page):
        if url.startswith(("data:", "#")):
            continue
        assert client.get(url).status_code == 200, url


def test_openapi_describes_the_multipart_upload(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    assert spec["info"]["version"] == "1"
    upload = spec["paths"]["/v1/jobs"]["post"]["requestBody"]["content"]["multipart/form-data"]
    assert set(upload["schema"]["properties"]) == {"images", "masks", "config", "webhook_url"}
    assert client.get("/docs").status_code == 200


def test_unknown_routes_and_methods_answer_json(client: TestClient) -> None:
    response = client.get("/v2/nothing")
    assert response.status_code == 404 and response.json()["error"]["code"] == "not_found"
    response = client.put("/v1/jobs")
    assert response.status_code == 405 and response.json()["error"]["code"] == "method_not_allowed"
