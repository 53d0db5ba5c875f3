"""`GET /v1/info` on this server's hardware: the default preset follows the workers' device
(a deployment's own choice wins) and each preset's expected time comes from the ETA table, or
from the times workers here measured."""

from __future__ import annotations

import redis
from fastapi.testclient import TestClient

from app.main import create_app
from app.state import DEFAULT_STAGE_SECONDS, PresetTime, StageHistory, Workers, preset_times
from app.state.eta import expected_job_seconds


def _info(settings) -> dict:  # type: ignore[no-untyped-def, type-arg]
    with TestClient(create_app(settings)) as client:
        response = client.get("/v1/info")
    assert response.status_code == 200, response.text
    return response.json()  # type: ignore[no-any-return]


def test_a_cpu_server_offers_preview_with_the_tables_times(make_settings) -> None:
    info = _info(make_settings(device="cpu", default_preset="auto"))
    assert info["device"] == "cpu" and info["default_preset"] == "preview"
    for preset in ("preview", "standard", "paper"):
        assert info["preset_times"][preset] == {
            "seconds": sum(DEFAULT_STAGE_SECONDS["cpu"][preset].values()), "measured": False}


def test_a_gpu_server_offers_standard(make_settings) -> None:
    info = _info(make_settings(device="cuda", default_preset="auto"))
    assert info["device"] == "cuda" and info["default_preset"] == "standard"
    assert info["preset_times"]["standard"]["seconds"] == sum(
        DEFAULT_STAGE_SECONDS["cuda"]["standard"].values())


def test_auto_follows_the_device_live_workers_announce(make_settings,
                                                       clean_redis: redis.Redis) -> None:
    settings = make_settings(device="auto", default_preset="auto")
    assert _info(settings)["default_preset"] == "preview"  # no worker up: the safe choice
    workers = Workers(clean_redis)
    workers.beat("cpu-box", 30, {"pid": 1, "device": "cpu"})
    assert _info(settings)["default_preset"] == "preview"
    workers.beat("gpu-box", 30, {"pid": 2, "device": "cuda"})
    info = _info(settings)
    assert info["device"] == "cuda" and info["default_preset"] == "standard"
    workers.forget("gpu-box")
    assert _info(settings)["device"] == "cpu"


def test_the_deployments_preset_wins(make_settings) -> None:
    assert _info(make_settings(device="cpu", default_preset="paper"))["default_preset"] == "paper"


def test_measured_times_replace_the_table(make_settings, clean_redis: redis.Redis) -> None:
    measured = {"masks": 1.0, "retrieval": 2.0, "phase1": 3.0, "phase2": 4.0, "phase3": 50.0,
                "render": 5.0, "export": 6.0}
    StageHistory(clean_redis).record("preview", "cpu", measured)
    info = _info(make_settings(device="cpu", default_preset="auto"))
    assert info["preset_times"]["preview"] == {"seconds": 71.0, "measured": True}
    assert expected_job_seconds("preview", "cpu", measured) == 71.0
    assert info["preset_times"]["standard"]["measured"] is False


def test_a_job_naming_no_preset_gets_the_servers_default(make_settings, photos) -> None:
    with TestClient(create_app(make_settings(device="cpu", default_preset="auto"))) as client:
        response = client.post("/v1/jobs", files=photos())
        assert response.status_code == 202, response.text
        assert client.get(f"/v1/jobs/{response.json()['id']}").json()["preset"] == "preview"


def test_info_answers_while_redis_is_down(make_settings) -> None:
    info = _info(make_settings(redis_url="redis://127.0.0.1:1/0", device="auto",
                               default_preset="auto"))
    assert info["device"] == "cpu" and info["default_preset"] == "preview"
    assert info["preset_times"]["preview"]["measured"] is False


def test_a_preset_without_a_table_or_a_measurement_has_no_time(clean_redis: redis.Redis) -> None:
    times = preset_times(StageHistory(clean_redis), ["preview", "custom"], "cuda")
    assert times["preview"] == PresetTime(sum(DEFAULT_STAGE_SECONDS["cuda"]["preview"].values()),
                                          measured=False)
    assert times["custom"] == PresetTime(None, measured=False)  # the page: "not measured yet"
