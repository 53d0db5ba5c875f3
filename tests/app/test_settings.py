"""The one Settings class: defaults, CADNERF_ variables, and failing fast with a clear message."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.main import create_app
from app.settings import SettingsError, hash_key, load_settings


def test_defaults_and_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("CADNERF_DATA_ROOT", "CADNERF_MAX_PHOTOS", "CADNERF_API_KEYS", "CADNERF_DEVICE",
                 "CADNERF_MASK_MODEL"):
        monkeypatch.delenv(name, raising=False)
    settings = load_settings()
    assert settings.data_root == Path("data/jobs") and settings.max_megapixels == 40
    assert (settings.min_photos, settings.max_photos) == (3, 10)
    assert settings.api_key_hashes == frozenset()
    monkeypatch.setenv("CADNERF_MAX_PHOTOS", "8")
    monkeypatch.setenv("CADNERF_API_KEYS", " a ,b,, ")
    monkeypatch.setenv("CADNERF_DEVICE", "cpu")
    settings = load_settings()
    assert settings.max_photos == 8 and settings.device == "cpu"
    assert settings.api_key_hashes == {hash_key("a"), hash_key("b")}
    assert settings.mask_model is None
    monkeypatch.setenv("CADNERF_MASK_MODEL", "")  # empty: unset
    assert load_settings().mask_model is None
    monkeypatch.setenv("CADNERF_MASK_MODEL", __file__)
    assert load_settings().mask_model == Path(__file__)


@pytest.mark.parametrize(("name", "value", "fragment"), [
    ("CADNERF_DEVICE", "gpu", "'auto', 'cpu' or 'cuda'"),
    ("CADNERF_MAX_PHOTOS", "many", "integer"),
    ("CADNERF_DEFAULT_PRESET", "turbo", "must be one of"),
    ("CADNERF_REDIS_URL", "http://x", "redis://"),
    ("CADNERF_MAX_MEGAPIXELS", "-1", "greater than 0"),
    ("CADNERF_MASK_MODEL", "/nonexistent/u2netp.onnx", "is not a file"),
])
def test_bad_values_name_the_variable(monkeypatch: pytest.MonkeyPatch, name: str, value: str,
                                      fragment: str) -> None:
    monkeypatch.setenv(name, value)
    with pytest.raises(SettingsError) as caught:
        load_settings()
    assert name in str(caught.value) and fragment in str(caught.value)


def test_inconsistent_limits_are_refused() -> None:
    with pytest.raises(SettingsError, match="CADNERF_MIN_PHOTOS"):
        load_settings(min_photos=5, max_photos=4)
    with pytest.raises(SettingsError, match="HARD_TIME_LIMIT"):
        load_settings(job_soft_time_limit_s=100, job_hard_time_limit_s=50)


def test_the_app_needs_a_redis_url(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CADNERF_REDIS_URL", raising=False)
    with pytest.raises(SettingsError, match="CADNERF_REDIS_URL"):
        create_app(load_settings(redis_url=""))


@pytest.mark.parametrize("command", ["serve", "worker"])
def test_commands_stop_at_start_up_on_a_bad_variable(command: str) -> None:
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "CADNERF_DEVICE": "gpu"}
    done = subprocess.run([sys.executable, "-m", "cadnerf_cli.main", command], cwd=root, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "CADNERF_DEVICE='gpu'" in done.stderr and "'auto', 'cpu' or 'cuda'" in done.stderr
