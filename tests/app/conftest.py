"""Fixtures for the API tests: settings on a temporary data root, a client, test images."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


from app.main import create_app  # noqa: E402
from app.settings import Settings, load_settings  # noqa: E402
from tests.app.images import image_bytes  # noqa: E402
from tests.configs import TINY_PRESET  # noqa: E402

MakeSettings = Callable[..., Settings]
# Per-key limits are off unless a test sets them (tests/app/test_fair_use.py): these tests
# submit many jobs as one owner to check other things.
FAIR_USE_OFF = {"max_queued_per_key": 0, "max_uploads_per_minute": 0}


@pytest.fixture()
def make_settings(tmp_path: Path, redis_url: str, clean_redis: object) -> MakeSettings:
    """Settings on a fresh data root and a flushed Redis database; keywords override fields."""
    library = tmp_path / "library"
    library.mkdir()
    manifest = {"spec": {"n_azimuths": 20, "elevations": [0, 15, 30, 45, 60]},
                "models": [{"id": "chair_01", "category": "chair", "kind": "object",
                            "source": "parametric", "licence": "CC0", "n_triangles": 120},
                           {"id": "cuboid_1x1x1", "category": "cuboid", "kind": "basic",
                            "source": "parametric", "licence": "CC0", "n_triangles": 12}]}
    (library / "manifest.json").write_text(json.dumps(manifest))

    def make(**overrides: object) -> Settings:
        values: dict[str, object] = {"redis_url": redis_url, "data_root": tmp_path / "jobs",
                                     "library_dir": library, "default_preset": TINY_PRESET}
        values.update(FAIR_USE_OFF)
        values.update(overrides)
        return load_settings(**values)

    return make


@pytest.fixture()
def settings(make_settings: MakeSettings) -> Settings:
    """Default test settings."""
    return make_settings()


@pytest.fixture()
def client(settings: Settings) -> Iterator[TestClient]:
    """A client of the app (its lifespan runs: data root created, cleanup started)."""
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture()
def photos() -> Callable[..., list[tuple[str, tuple[str, bytes, str]]]]:
    """Multipart `images` entries: photos(n, size=..., fmt=...)."""
    def make(n: int = 3, size: tuple[int, int] = (80, 64),
             fmt: str = "PNG") -> list[tuple[str, tuple[str, bytes, str]]]:
        ext = {"PNG": "png", "JPEG": "jpg", "WEBP": "webp"}[fmt]
        return [("images", (f"photo_{i}.{ext}", image_bytes(size, fmt, 40 + 40 * i),
                            f"image/{'jpeg' if ext == 'jpg' else ext}")) for i in range(n)]
    return make
