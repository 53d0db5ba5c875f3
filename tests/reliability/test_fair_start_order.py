"""Fair order over HTTP with a real worker: a key with one job is not stuck behind another
key's thirty (the jobs are taken round-robin across keys, not first come first served)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import redis

from tests.configs import tiny_request
from tests.redis_fixture import _with_db
from tests.reliability import jobs, support
from tests.reliability.support import Live, start_live, stop_live

pytestmark = pytest.mark.slow

KEY_A = {"Authorization": "Bearer fair-a"}
KEY_B = {"Authorization": "Bearer fair-b"}


@pytest.fixture()
def keyed_service(rel_redis_url: str, tiny_library_dir: Path,
                  tmp_path: Path) -> Iterator[Live]:
    """API with two keys + one worker, on a Redis database of its own."""
    url = _with_db(rel_redis_url, support.FAIR_DB)
    client = redis.Redis.from_url(url)
    client.flushdb()
    live = start_live(tmp_path / "service", url, tiny_library_dir, api_keys="fair-a,fair-b")
    yield live
    stop_live(live)
    client.flushdb()
    client.close()


def _started(url: str, job_id: str, headers: dict[str, str]) -> float | None:
    body = httpx.get(f"{url}/v1/jobs/{job_id}", headers=headers, timeout=10).json()
    return body.get("started_at")


def test_key_b_starts_before_key_as_third_job(keyed_service: Live,
                                              photo_set: list[Path]) -> None:
    url = keyed_service.url
    config = tiny_request()
    a_ids = [jobs.submit(url, photo_set, config, headers=KEY_A)["id"] for _ in range(30)]
    b_job = jobs.submit(url, photo_set, config, headers=KEY_B)
    assert b_job["queue_position"] is not None and b_job["queue_position"] <= 1
    give_up = time.monotonic() + 600  # guards against a hang only: the test is the order
    while (b_start := _started(url, b_job["id"], KEY_B)) is None:
        assert time.monotonic() < give_up, \
            f"key B's job never started (600 s)\n{keyed_service.logs()}"
        time.sleep(0.5)
    third = _started(url, a_ids[2], KEY_A)
    assert third is None or third > b_start, "key A's third job started before key B's first"
    for job_id in a_ids:  # the rest need not run
        assert httpx.delete(f"{url}/v1/jobs/{job_id}", headers=KEY_A,
                            timeout=30).status_code == 200
