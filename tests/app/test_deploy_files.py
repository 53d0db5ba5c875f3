"""docker-compose.yml and the Dockerfile agree with the settings and the commands."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from app.state.settings import ENV_PREFIX, Settings, load_settings

ROOT = Path(__file__).resolve().parents[2]


def _compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_compose_services_and_health_checks() -> None:
    services = _compose()["services"]
    assert set(services) == {"redis", "api", "worker"}
    assert services["redis"]["command"][-2:] == ["--appendonly", "yes"]
    assert services["redis"]["healthcheck"]["test"] == ["CMD", "redis-cli", "ping"]
    assert "/healthz" in " ".join(services["api"]["healthcheck"]["test"])
    assert services["api"]["command"][3] == "serve" and services["worker"]["command"][3] == "worker"
    assert services["api"]["volumes"] == services["worker"]["volumes"] == ["jobs:/data/jobs"]


def test_compose_variables_are_settings_that_load() -> None:
    environment = _compose()["services"]["worker"]["environment"]
    fields = {f"{ENV_PREFIX}{name.upper()}" for name in Settings.model_fields}
    assert set(environment) <= fields
    resolved = {}
    for name, value in environment.items():  # ${VAR:-default} -> default
        match = re.fullmatch(r"\$\{\w+:-(.*)\}", str(value))
        resolved[name.removeprefix(ENV_PREFIX).lower()] = match.group(1) if match else value
    settings = load_settings(**resolved)
    assert settings.redis_url == "redis://redis:6379/0"
    assert str(settings.data_root) == "/data/jobs"


def test_dockerfile_installs_cpu_torch_first() -> None:
    text = (ROOT / "Dockerfile").read_text()
    torch_at = text.index("torch==2.13.0")
    assert "download.pytorch.org/whl/cpu" in text
    assert torch_at < text.index("pip install .")
