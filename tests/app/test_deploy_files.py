"""docker-compose.yml and the Dockerfile agree with the settings and the commands."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from app.settings import ENV_PREFIX, Settings, load_settings

ROOT = Path(__file__).resolve().parents[2]


def _compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_compose_services_and_health_checks() -> None:
    services = _compose()["services"]
    assert set(services) == {"redis", "minio", "bucket", "api", "worker"}
    assert services["redis"]["command"][-2:] == ["--appendonly", "yes"]
    assert services["redis"]["healthcheck"]["test"] == ["CMD", "redis-cli", "ping"]
    assert "/healthz" in " ".join(services["api"]["healthcheck"]["test"])
    assert services["api"]["command"][3] == "serve" and services["worker"]["command"][3] == "worker"


def test_compose_api_and_workers_share_no_disk_only_the_object_store() -> None:
    compose = _compose()
    services = compose["services"]
    assert "volumes" not in services["api"] and "volumes" not in services["worker"]
    assert "jobs" not in compose["volumes"]
    environment = services["worker"]["environment"]
    assert environment == services["api"]["environment"]
    assert str(environment["CADNERF_STORAGE_URL"]).endswith("s3://cadnerf/jobs}")
    assert "http://minio:9000" in str(environment["AWS_ENDPOINT_URL"])
    assert "mb --ignore-existing store/cadnerf" in " ".join(services["bucket"]["command"])
    for name in ("api", "worker"):
        assert services[name]["depends_on"]["bucket"]["condition"] == \
            "service_completed_successfully"


def test_compose_variables_are_settings_that_load() -> None:
    environment = {k: v for k, v in _compose()["services"]["worker"]["environment"].items()
                   if not k.startswith("AWS_")}  # boto3's own variables
    fields = {f"{ENV_PREFIX}{name.upper()}" for name in Settings.model_fields}
    assert set(environment) <= fields
    resolved = {}
    for name, value in environment.items():  # ${VAR:-default} -> default
        match = re.fullmatch(r"\$\{\w+:-(.*)\}", str(value))
        resolved[name.removeprefix(ENV_PREFIX).lower()] = match.group(1) if match else value
    settings = load_settings(**resolved)
    assert settings.redis_url == "redis://redis:6379/0"
    assert str(settings.data_root) == "/data/jobs"
    assert settings.storage_url == "s3://cadnerf/jobs"


def test_dockerfile_installs_cpu_torch_first() -> None:
    text = (ROOT / "Dockerfile").read_text()
    torch_at = text.index("torch==2.13.0")
    assert "download.pytorch.org/whl/cpu" in text
    assert torch_at < text.index("pip install .")
