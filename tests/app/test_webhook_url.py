"""Webhook URLs at the door: hosts that are plainly internal are refused (SSRF), unless allowed."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from app.errors import ApiError
from app.main import create_app
from app.settings import Settings, load_settings, non_public_reason
from app.uploads import parse_webhook

INTERNAL = [
    "http://127.0.0.1:6379/",  # the Redis port
    "http://10.0.0.5/hook",
    "http://192.168.1.20/hook",
    "http://169.254.169.254/latest/meta-data/",  # cloud metadata
    "http://100.100.100.200/",  # carrier-grade NAT range, another cloud's metadata
    "http://0.0.0.0:8000/",
    "http://2130706433/",  # 127.0.0.1 written as a number
    "http://[::1]/hook",
    "http://[fe80::1]/hook",
    "http://[fd00::1]/hook",
    "http://[::ffff:127.0.0.1]/hook",  # IPv4-mapped IPv6
    "http://localhost:8000/hook",
    "https://LOCALHOST./hook",
    "http://api.localhost/hook",
]


@pytest.mark.parametrize("url", INTERNAL)
def test_internal_hosts_are_refused_with_422(client: TestClient, settings: Settings, photos,
                                             url: str) -> None:
    response = client.post("/v1/jobs", files=photos(), data={"webhook_url": url})
    assert response.status_code == 422, response.text
    error = response.json()["error"]
    assert error["code"] == "webhook_url_not_public" and error["field"] == "webhook_url"
    assert "CADNERF_WEBHOOK_ALLOW_PRIVATE" in error["hint"]
    assert not settings.data_root.exists() or list(settings.data_root.iterdir()) == []


@pytest.mark.parametrize("url", ["http://93.184.216.34/hook", "https://[2606:4700::1111]/x",
                                 "https://hooks.example.com/cadnerf?token=1"])
def test_public_hosts_are_accepted(client: TestClient, photos, url: str) -> None:
    response = client.post("/v1/jobs", files=photos(), data={"webhook_url": url})
    assert response.status_code == 202, response.text


def test_the_setting_allows_private_hosts(make_settings, photos) -> None:
    with TestClient(create_app(make_settings(webhook_allow_private=True))) as client:
        response = client.post("/v1/jobs", files=photos(),
                               data={"webhook_url": "http://127.0.0.1:9000/hook"})
    assert response.status_code == 202, response.text


def test_parse_webhook_names_the_host_and_reason() -> None:
    with pytest.raises(ApiError) as caught:
        parse_webhook("http://169.254.169.254/latest/")
    assert caught.value.status == 422
    assert "169.254.169.254" in caught.value.detail.message
    assert "link-local" in caught.value.detail.message
    assert parse_webhook("http://169.254.169.254/latest/", allow_private=True) == (
        "http://169.254.169.254/latest/")
    assert parse_webhook("") is None and parse_webhook(None) is None


@pytest.mark.parametrize(("address", "fragment"), [
    ("127.0.0.2", "loopback"), ("::1", "loopback"), ("::ffff:10.1.2.3", "private"),
    ("fe80::1%eth0", "link-local"), ("224.0.0.1", "multicast"), ("::", "unspecified"),
    ("240.0.0.1", "reserved"), ("100.64.0.1", "globally routable"),
])
def test_non_public_addresses_are_named(address: str, fragment: str) -> None:
    reason = non_public_reason(address)
    assert reason is not None and fragment in reason


@pytest.mark.parametrize("address", ["8.8.8.8", "93.184.216.34", "2606:4700::1111"])
def test_public_addresses_pass(address: str) -> None:
    assert non_public_reason(address) is None


def test_the_setting_is_off_by_default_and_read_from_the_environment(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CADNERF_WEBHOOK_ALLOW_PRIVATE", raising=False)
    assert load_settings().webhook_allow_private is False
    monkeypatch.setenv("CADNERF_WEBHOOK_ALLOW_PRIVATE", "true")
    assert load_settings().webhook_allow_private is True
