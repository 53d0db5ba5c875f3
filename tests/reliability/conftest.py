"""Fixtures of the reliability suite: a real Redis (its own database), settings in a sandbox,
an in-process client, and a live uvicorn + worker pair in subprocesses."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import redis
from fastapi.testclient import TestClient

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from app.main import create_app  # noqa: E402
from app.settings import Settings, load_settings  # noqa: E402
from tests.configs import TINY_PRESET  # noqa: E402
from tests.redis_fixture import (  # noqa: E402,F401  (helpers and the session hook)
    _answers,
    _embedded_url,
    _with_db,
    flushed_client,
    flushed_database,
    pytest_sessionfinish,
)
from tests.reliability import support  # noqa: E402
from tests.reliability.support import Live, start_live, stop_live  # noqa: E402

MakeSettings = Callable[..., Settings]
# Per-key limits are off unless a test sets them (tests/app/test_fair_use.py): these tests
# submit many jobs as one owner to check other things.
FAIR_USE_OFF = {"max_queued_per_key": 0, "max_uploads_per_minute": 0}


@pytest.fixture(scope="session")
def rel_redis_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A Redis database of our own (13): the configured/local server, else an embedded one."""
    yield from flushed_database(support.RELIABILITY_DB, tmp_path_factory)


@pytest.fixture()
def rel_redis(rel_redis_url: str) -> Iterator[redis.Redis]:
    """A client of our database, flushed before the test."""
    yield from flushed_client(rel_redis_url)


@pytest.fixture()
def sandbox(tmp_path: Path) -> Path:
    """The parent of the data root: nothing but the job root may change under it."""
    folder = tmp_path / "sandbox"
    (folder / "jobs").mkdir(parents=True)
    library = folder / "library"
    library.mkdir()
    manifest = {"spec": {"n_azimuths": 20, "elevations": [0, 15, 30, 45, 60]},
                "models": [{"id": "cuboid_1x1x1", "category": "cuboid", "kind": "basic"}]}
    (library / "manifest.json").write_text(json.dumps(manifest))
    return folder


@pytest.fixture()
def make_settings(sandbox: Path, rel_redis_url: str, rel_redis: redis.Redis) -> MakeSettings:
    """Settings on the sandbox's data root and our flushed Redis database."""
    def make(**overrides: object) -> Settings:
        values: dict[str, object] = {"redis_url": rel_redis_url, "data_root": sandbox / "jobs",
                                     "library_dir": sandbox / "library",
                                     "default_preset": TINY_PRESET}
        values.update(FAIR_USE_OFF)
        values.update(overrides)
        return load_settings(**values)

    return make


@pytest.fixture()
def client(make_settings: MakeSettings) -> Iterator[TestClient]:
    """An in-process client of the app (lifespan run), raising no server exceptions."""
    with TestClient(create_app(make_settings()), raise_server_exceptions=False) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def live_api(rel_redis_url: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """A uvicorn subprocess without a worker (uploads only)."""
    redis.Redis.from_url(rel_redis_url).flushdb()
    folder = tmp_path_factory.mktemp("live_api")
    library = folder / "library"
    library.mkdir()
    (library / "manifest.json").write_text(json.dumps({"models": []}))
    live = start_live(folder, rel_redis_url, library, with_worker=False)
    yield live
    stop_live(live)


@pytest.fixture(scope="session")
def service(rel_redis_url: str, tiny_library_dir: Path,
            tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """API (uvicorn subprocess) + one `cadnerf worker` on a fresh data root, for the session.

    On a Redis database of its own: its worker must not take the jobs that in-process tests
    queue (and those tests flush their database)."""
    url = _with_db(rel_redis_url, support.LIVE_DB)
    client = redis.Redis.from_url(url)
    client.flushdb()
    live = start_live(tmp_path_factory.mktemp("service"), url, tiny_library_dir)
    yield live
    stop_live(live)
    client.flushdb()
    client.close()


@pytest.fixture(scope="session")
def photo_set(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Four 64 px RGBA renders of a box walked around (alpha = mask)."""
    return support.render_photo_set(tmp_path_factory.mktemp("photos"))

